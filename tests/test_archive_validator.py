"""Archives pass the RO-Crate validator (roc-validator) offline, Process Run Crate profile.

The validator fetches the JSON-LD context the crate declares (RO-Crate 1.1, which Process Run
Crate 0.5 is a profile of) twice: its own check through its HTTP requester, and rdflib when it
parses the JSON-LD. Both are served here, for that address, the term definitions of the context
file that ``rocrate`` ships (RO-Crate 1.3, which keeps every 1.1 term's IRI; the test checks that
every term the crate uses is defined there, so nothing expands by accident). Any other address
fails the test, so nothing goes online.
"""

from __future__ import annotations

import json
import zipfile
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from session_factory import make_session
from test_archive import CONFIG, _results

from huefringe import archive
from huefringe.archive import read_crate, write_archive
from huefringe.settings import load_config, software_identity

rocrate_validator = pytest.importorskip("rocrate_validator")
from rocrate_validator import services  # noqa: E402
from rocrate_validator.models import Severity, ValidationSettings  # noqa: E402

#: what a lab sets: its licence, a Person with an ORCID and an affiliation, a publisher with a ROR
#: id and a url (huefringe's own identity comes from the installed distribution's metadata)
ARCHIVE_CFG = {
    "license": {"id": "https://spdx.org/licenses/CC-BY-4.0", "name": "Creative Commons Attribution 4.0 International"},
    "author": {"name": "J. Doe", "id": "https://orcid.org/0000-0002-1825-0097",
               "affiliation": {"name": "Example Metrology Lab", "id": "https://ror.org/03yrm5c26", "url": "https://example.org/lab"}},
    "publisher": {"name": "Example Metrology Lab", "id": "https://ror.org/03yrm5c26", "url": "https://example.org/lab"},
}
PROVENANCE = ("provenance:\n  captured_at: 2026-11-30T14:05:00Z\n  operator: J. Doe\n"
              "  instrument: bench-2 (DLP 1024x768, 8-bit colour camera)\n  simulated: true\n  notes: test\n")
#: RECOMMENDED checks that pass at the default configuration:
#: application url, SoftwareApplication @id an absolute URI (both from [project.urls] of
#: pyproject.toml), the run's endTime (deterministic, the date of datePublished)
FIXED_CHECKS = {"process-run-crate-0.5_3.2", "process-run-crate-0.5_5.1", "process-run-crate-0.5_8.4"}
#: the one RECOMMENDED check left to the lab at the default configuration: every Organization
#: (the default author and publisher) SHOULD have a url, which only the lab knows
LAB_CHECKS = {"ro-crate-1.1_31.2"}
CONTEXT_URL = "https://w3id.org/ro/crate/1.1/context"


def _context_document() -> dict[str, Any]:
    return json.loads(resources.files("rocrate").joinpath("data/ro-crate.jsonld").read_text())


class _Response:
    status_code = 200
    headers = {"Content-Type": "application/ld+json"}

    def __init__(self, doc: dict[str, Any]):
        self._doc = doc

    def json(self) -> dict[str, Any]:
        return self._doc


@pytest.fixture
def offline(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Serve the RO-Crate 1.3 context locally to the validator and to rdflib; refuse anything else."""
    import rdflib.plugins.shared.jsonld.context as jsonld_context
    from rocrate_validator.utils.http import HttpRequester

    shipped = _context_document()
    doc = {"@id": CONTEXT_URL, "@context": shipped["@context"]}
    served: list[str] = []
    known = {CONTEXT_URL}

    def local(url: str) -> dict[str, Any]:
        if str(url) not in known:
            raise AssertionError(f"the validator tried to fetch {url} (the test runs offline)")
        served.append(str(url))
        return doc

    monkeypatch.setattr(HttpRequester, "get", lambda self, url, *a, **k: _Response(local(url)), raising=False)
    original = jsonld_context.source_to_json

    def source_to_json(source: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(source, str) and source.startswith("http"):
            return local(source), None
        return original(source, *args, **kwargs)

    monkeypatch.setattr(jsonld_context, "source_to_json", source_to_json)
    return served


def _validate(crate_dir: Path, severity: Severity) -> Any:
    settings = ValidationSettings(
        rocrate_uri=str(crate_dir),
        profile_identifier="process-run-crate",
        requirement_severity=severity,
    )
    return services.validate(settings)


def _failed(result: Any, severity: Severity) -> dict[str, set[str]]:
    """check id -> the ids of the entities that fail it."""
    out: dict[str, set[str]] = {}
    for i in result.get_issues(severity):
        entity = str(getattr(i.violatingEntity, "id", i.violatingEntity))
        out.setdefault(i.check.identifier, set()).add(entity.removeprefix("./"))  # "#x", resolved against the root
    return out


def _archive(tmp_path: Path, *, provenance: bool, config: dict[str, Any]) -> Path:
    session = make_session(tmp_path / "s", bands=6, repeats=1, frames=1, phase_shift=False)
    if provenance:
        with open(session / "session.yaml", "a") as f:
            f.write(PROVENANCE)
    results = _results(tmp_path / "results")
    out = write_archive(session, results, tmp_path / "a.zip", config=config)
    folder = tmp_path / "crate"
    with zipfile.ZipFile(out) as zf:
        zf.extractall(folder)
    return folder


@pytest.mark.parametrize("severity", [Severity.REQUIRED, Severity.RECOMMENDED])
@pytest.mark.parametrize("provenance", [True, False])
def test_archive_passes_roc_validator_offline(tmp_path: Path, offline: list[str], severity: Severity,
                                              provenance: bool) -> None:
    folder = _archive(tmp_path, provenance=provenance, config={**CONFIG, "archive": ARCHIVE_CFG})
    result = _validate(folder, severity)
    issues = [f"{i.check.identifier} {i.check.name}: {i.message}" for i in result.get_issues(severity)]
    assert result.passed(severity), "\n".join(sorted(set(issues)))
    assert offline, "the context was never requested: the check did not run"


@pytest.mark.parametrize("provenance", [True, False])
def test_default_configuration_leaves_only_the_labs_identity(tmp_path: Path, offline: list[str],
                                                              provenance: bool) -> None:
    """At the packaged defaults every REQUIRED and RECOMMENDED check passes but the Organization
    url (the default author and publisher are placeholders for the lab's own)."""
    folder = _archive(tmp_path, provenance=provenance, config={**CONFIG, "archive": load_config()["archive"]})
    assert _validate(folder, Severity.REQUIRED).passed(Severity.REQUIRED)
    result = _validate(folder, Severity.RECOMMENDED)
    executed = {c.identifier for c in result.executed_checks}
    assert FIXED_CHECKS | LAB_CHECKS <= executed and len(executed) > 50
    failed = _failed(result, Severity.RECOMMENDED)
    assert set(failed) == LAB_CHECKS, failed
    by_id = {e["@id"]: e for e in read_crate(folder)["@graph"]}
    root = by_id["./"]
    assert failed["ro-crate-1.1_31.2"] == {root["publisher"]["@id"], root["author"]["@id"]}
    assert all(by_id[e]["@type"] == "Organization" for e in failed["ro-crate-1.1_31.2"])
    app = by_id[by_id[root["mentions"]["@id"]]["instrument"]["@id"]]
    identity = software_identity()
    assert identity.url and identity.url.startswith("https://")
    assert app["@id"] == app["url"] == identity.url and app["version"] == identity.version


@pytest.mark.parametrize("lab", ["urls", "person"])
def test_the_labs_keys_make_the_rest_pass(tmp_path: Path, offline: list[str], lab: str) -> None:
    """The default author and publisher with a url each, or a Person author with an affiliation."""
    cfg = load_config({"archive": {"author": {"url": "https://example.org/bench"}, "publisher": {"url": "https://example.org/lab"}}}
                      )["archive"] if lab == "urls" else ARCHIVE_CFG
    folder = _archive(tmp_path, provenance=False, config={**CONFIG, "archive": cfg})
    result = _validate(folder, Severity.RECOMMENDED)
    assert not _failed(result, Severity.RECOMMENDED)
    assert result.passed(Severity.RECOMMENDED)


def test_end_time_is_the_publication_date_in_the_checked_form(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    by_id = {e["@id"]: e for e in read_crate(_archive(tmp_path / "a", provenance=True, config=CONFIG))["@graph"]}
    assert by_id["#run-test-session"]["endTime"] == "2026-11-30T14:05:00+00:00"  # datePublished 2026-11-30T14:05:00Z
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764511500")
    by_id = {e["@id"]: e for e in read_crate(_archive(tmp_path / "b", provenance=False, config=CONFIG))["@graph"]}
    assert by_id["./"]["datePublished"] == "2025-11-30T14:05:00Z"
    assert by_id["#run-test-session"]["endTime"] == "2025-11-30T14:05:00+00:00"
    assert archive._end_time("2026-11-30") == "2026-11-30"
    assert archive._end_time("2026-11-30T09:05:00.25-05:00") == "2026-11-30T14:05:00.250+00:00"
    assert archive._end_time("2026-11-30T14:05") == "2026-11-30"  # no zone: the date only, not a guessed zone


def test_software_url_in_the_configuration_overrides_the_projects(tmp_path: Path) -> None:
    folder = _archive(tmp_path, provenance=False, config={**CONFIG, "archive": {"software_url": "https://example.org/hf"}})
    by_id = {e["@id"]: e for e in read_crate(folder)["@graph"]}
    assert by_id["https://example.org/hf"]["url"] == "https://example.org/hf"
    assert software_identity().url not in by_id


def _terms(node: Any) -> set[str]:
    if isinstance(node, dict):
        keys = {k for k in node if not k.startswith("@")}
        types = {t for t in ([node["@type"]] if isinstance(node.get("@type"), str) else node.get("@type", []))}
        return keys | types | set().union(*(_terms(v) for v in node.values()))
    if isinstance(node, list):
        return set().union(*(_terms(v) for v in node)) if node else set()
    return set()


def test_crate_entities_for_auditors(tmp_path: Path) -> None:
    folder = _archive(tmp_path, provenance=True, config={**CONFIG, "archive": ARCHIVE_CFG})
    crate = read_crate(folder)
    assert crate["@context"] == [CONTEXT_URL, {"sha256": "https://w3id.org/ro/terms/workflow-run#sha256"}]
    undefined = _terms(crate["@graph"]) - set(_context_document()["@context"]) - {"sha256"}
    assert not undefined  # every term is in the context served offline
    by_id = {e["@id"]: e for e in crate["@graph"]}
    root = by_id["./"]
    assert root["datePublished"] == "2026-11-30T14:05:00Z"  # the capture date, not the clock
    assert root["license"] == {"@id": "https://spdx.org/licenses/CC-BY-4.0"}
    assert by_id["https://spdx.org/licenses/CC-BY-4.0"]["@type"] == "CreativeWork"
    assert by_id[root["publisher"]["@id"]]["@type"] == "Organization"
    assert by_id[root["author"]["@id"]]["@type"] == "Person" and by_id[root["author"]["@id"]]["name"] == "J. Doe"
    run = by_id["#run-test-session"]
    assert run["result"] == {"@id": "results/"} and run["agent"] == root["author"]
    assert root["mentions"] == {"@id": "#run-test-session"}
    assert {"@id": "https://w3id.org/ro/wfrun/process/0.5"} in by_id["ro-crate-metadata.json"]["conformsTo"]
    session = by_id["session/"]
    assert session["dateCreated"] == "2026-11-30T14:05:00Z" and "SIMULATED" in session["description"]
    assert by_id[session["creator"]["@id"]]["name"] == "J. Doe"
    assert "simulated data" in root["keywords"]


def test_without_capture_date_the_placeholder_date_says_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    root = {e["@id"]: e for e in read_crate(_archive(tmp_path, provenance=False, config=CONFIG))["@graph"]}["./"]
    assert root["datePublished"] == "1980-01-01T00:00:00Z" and "datePublished: a placeholder" in root["description"]
