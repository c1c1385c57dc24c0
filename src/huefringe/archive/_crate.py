"""The RO-Crate JSON-LD document of an archive (Process Run Crate 0.5), built with ``rocrate``."""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import json
import re
from collections.abc import Mapping
from pathlib import PurePosixPath
from typing import Any
from urllib.parse import quote

import yaml

from huefringe.io import source_date_epoch
from huefringe.report import software_versions

from ._members import (
    CONFORMS_TO,
    DEFAULT_LICENSE,
    EXTRA_TERMS,
    PROCESS_RUN_PROFILE,
    RESULTS_DIR,
    RO_CRATE_VERSION,
    SESSION_DIR,
    ZIP_EPOCH,
    ArchiveError,
    _Member,
    encoding_format,
)


def _date_published(provenance: Mapping[str, Any] | None = None) -> tuple[str, str]:
    """``datePublished`` of the crate and a note saying where it comes from.

    In order: the session's ``provenance.captured_at`` (the data are as old as their capture);
    ``SOURCE_DATE_EPOCH`` (the reproducible-builds convention); otherwise the ZIP epoch
    1980-01-01, which the note (written into the root's description) calls a placeholder.
    Never the clock or a file's modification time, so the same inputs give the same bytes.
    """
    when = (provenance or {}).get("captured_at")
    if when:
        return str(when), "the capture date (provenance.captured_at of session.yaml)"
    try:
        t = source_date_epoch()
    except ValueError as exc:
        raise ArchiveError(str(exc)) from exc
    if t is not None:
        return t.strftime("%Y-%m-%dT%H:%M:%SZ"), "SOURCE_DATE_EPOCH given when the archive was written"
    t = _dt.datetime(*ZIP_EPOCH, tzinfo=_dt.UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%SZ"), (
        "a placeholder (the ZIP epoch): the session has no provenance.captured_at and SOURCE_DATE_EPOCH "
        "was not set, and the clock is not used so that the same inputs give the same archive")


def _end_time(date_published: str) -> str:
    """The run's ``endTime``: ``datePublished`` in the form Process Run Crate 0.5 checks.

    Its pattern is a date, or a date-time with seconds (optionally milliseconds) and a ``+HH:MM``
    offset, so a zoned time is written in UTC as ``+00:00`` (``Z`` and negative offsets do not
    match) and a time without a zone keeps its date only (a zone would be a guess).
    """
    when = _dt.datetime.fromisoformat(date_published)
    if len(date_published) == 10 or when.tzinfo is None:
        return when.date().isoformat()
    when = when.astimezone(_dt.UTC)
    return when.isoformat(timespec="milliseconds" if when.microsecond else "seconds")


def _runtime_requirements() -> list[str]:
    """Distribution names of huefringe's runtime requirements (extras excluded), sorted."""
    try:
        reqs = importlib.metadata.requires("huefringe") or []
    except importlib.metadata.PackageNotFoundError:
        return []
    names = set()
    for r in reqs:
        if "extra ==" in r.replace('"', "").replace("'", ""):
            continue
        m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", r)
        if m:
            names.add(m.group(1).lower())
    return sorted(names)


def _software() -> dict[str, str]:
    """``{"python", "platform", "huefringe", <requirement>: version}``."""
    return software_versions(["huefringe", *_runtime_requirements()])


def _ref(name: str) -> dict[str, str]:
    return {"@id": quote(name, safe="/")}


def _config_bytes(config: Mapping[str, Any]) -> bytes:
    plain = json.loads(json.dumps(dict(config), default=str))  # Snakemake config objects -> plain data
    return yaml.safe_dump(plain, sort_keys=True, default_flow_style=False, allow_unicode=True).encode("utf-8")


def _contextual_id(given: str | None, local: str) -> str:
    return given if given else local


def _entity(crate: Any, eid: str, etype: str, props: dict[str, Any]) -> dict[str, str]:
    """Add a contextual entity to ``crate``; its reference."""
    from rocrate.model import ContextEntity

    crate.add(ContextEntity(crate, eid, properties={"@type": etype, **props}))
    return {"@id": eid}


def _organization(crate: Any, org: Mapping[str, Any], local: str) -> dict[str, str]:
    """An Organization entity (``{"name", "id"?, "url"?}``; ``local`` the id without one)."""
    props = {"name": str(org["name"])}
    if org.get("url"):
        props["url"] = str(org["url"])
    return _entity(crate, _contextual_id(org.get("id"), local), "Organization", props)


def _author(crate: Any, author: Mapping[str, Any]) -> dict[str, str]:
    """The author entity (``{"name", "id"?, "type"?, "url"?, "affiliation"?}``, Person by default)."""
    props: dict[str, Any] = {"name": str(author["name"])}
    if author.get("url"):
        props["url"] = str(author["url"])
    if author.get("affiliation"):
        props["affiliation"] = _organization(crate, author["affiliation"], "#affiliation")
    return _entity(crate, _contextual_id(author.get("id"), "#author"), str(author.get("type", "Person")), props)


def _software_id(software: Mapping[str, str], name: str, software_url: str | None) -> tuple[str, str | None]:
    """The ``@id`` and home page of distribution ``name`` (huefringe: ``software_url`` or local)."""
    version = quote(software[name], safe="")
    if name == "huefringe":
        return (software_url, software_url) if software_url else ("#software/huefringe", None)
    if name == "python":
        return f"https://www.python.org/downloads/release/python-{version.replace('.', '')}/", "https://www.python.org/"
    return f"https://pypi.org/project/{quote(name, safe='')}/{version}/", f"https://pypi.org/project/{quote(name, safe='')}/"


def _add_software(crate: Any, software: Mapping[str, str], software_url: str | None) -> dict[str, str] | None:
    """A SoftwareApplication per distribution; huefringe's reference (the run's instrument), if listed."""
    platform_name = software.get("platform")
    sw_ids = {}
    for name in sorted(n for n in software if n != "platform"):
        sid, url = _software_id(software, name, software_url)
        sw_ids[name] = sid
        props: dict[str, Any] = {"name": "Python" if name == "python" else name, "version": software[name]}
        if url:
            props["url"] = url
        if name == "huefringe" and platform_name:
            props["operatingSystem"] = platform_name
        _entity(crate, sid, "SoftwareApplication", props)
    instrument = {"@id": sw_ids["huefringe"]} if "huefringe" in sw_ids else None
    if instrument:  # the other distributions are what huefringe ran on
        crate.dereference(sw_ids["huefringe"])["softwareRequirements"] = [
            {"@id": sid} for name, sid in sw_ids.items() if name != "huefringe"]
    return instrument


def _add_file(crate: Any, m: _Member, description: str | None = None) -> dict[str, str]:
    """A File data entity of member ``m`` (name, size, format, SHA-256); its reference."""
    props: dict[str, Any] = {
        "name": PurePosixPath(m.name).name,
        "contentSize": str(m.size),
        "encodingFormat": encoding_format(m.name),
        "sha256": m.sha256,
    }
    if description:
        props["description"] = description
    crate.add_file(dest_path=m.name, properties=props)
    return _ref(m.name)


def _provenance_sentences(prov: Mapping[str, Any]) -> list[str]:
    """What the session's provenance block tells about the capture, as sentences."""
    told = []
    if prov.get("instrument"):
        told.append(f"Instrument: {prov['instrument']}.")
    if "simulated" in prov:
        told.append("SIMULATED: written by a virtual bench, not captured by a physical rig." if prov["simulated"]
                    else "Captured by a physical rig (not simulated).")
    if prov.get("notes"):
        told.append(f"Notes: {prov['notes']}")
    return told


def build_crate(
    session_id: str,
    inputs: list[_Member],
    outputs: list[_Member],
    config: _Member | None,
    software: Mapping[str, str],
    *,
    date_published: str,
    date_note: str = "",
    license: Mapping[str, str] | str | None = None,
    author: Mapping[str, str] | None = None,
    publisher: Mapping[str, str] | None = None,
    provenance: Mapping[str, Any] | None = None,
    software_url: str | None = None,
    session_format: str = "capture-session/1",
) -> dict[str, Any]:
    """The RO-Crate JSON-LD document of an archive (see the module docstring), built with ``rocrate``.

    ``license`` is ``{"id": URI, "name": ...}`` (a plain string becomes the description of a
    local ``#license`` entity); ``author`` ``{"name", "id"?, "type"?, "url"?, "affiliation"?}``
    (Person by default);
    ``publisher`` ``{"name", "id"?, "url"?}`` (always an Organization); ``provenance`` the
    session's provenance block, recorded on the root dataset and the run; ``session_format`` the
    session's ``format`` (capture-session/1 or structured-light-session/1).
    """
    from rocrate.rocrate import ROCrate

    crate = ROCrate(version=RO_CRATE_VERSION, gen_preview=False)
    crate.metadata.extra_terms.update(EXTRA_TERMS)
    crate.metadata["conformsTo"] = [{"@id": CONFORMS_TO}, {"@id": PROCESS_RUN_PROFILE}]
    prov = dict(provenance or {})

    def entity(eid: str, etype: str, props: dict[str, Any]) -> dict[str, str]:
        return _entity(crate, eid, etype, props)

    # contextual entities: profile, licence, author, publisher
    profile_ref = entity(PROCESS_RUN_PROFILE, "CreativeWork", {"name": "Process Run Crate", "version": "0.5"})
    if isinstance(license, Mapping):
        license_ref = entity(str(license["id"]), "CreativeWork", {"name": str(license["name"])})
    else:
        license_ref = entity("#license", "CreativeWork", {
            "name": "licence not specified", "description": str(license or DEFAULT_LICENSE)})
    author_ref = _author(crate, author) if author else None
    pub = dict(publisher or {"name": "not specified (set archive.publisher in the configuration)"})
    publisher_ref = _organization(crate, pub, "#publisher")
    instrument = _add_software(crate, software, software_url)

    # data entities
    config_ref = (_add_file(crate, config, "Workflow configuration used for the run (keys of config.yaml).")
                  if config else None)
    input_refs = [_add_file(crate, m) for m in inputs]
    output_refs = [_add_file(crate, m) for m in outputs]
    session_props: dict[str, Any] = {
        "name": f"capture session {session_id} (inputs)",
        "description": f"The session folder the workflow read ({session_format}).",
        "hasPart": input_refs,
    }
    if prov.get("captured_at"):
        session_props["dateCreated"] = str(prov["captured_at"])
    if prov.get("operator"):
        session_props["creator"] = entity("#operator", "Person", {"name": str(prov["operator"])})
    told = _provenance_sentences(prov)
    if told:
        session_props["description"] += " " + " ".join(told)
    crate.add_dataset(dest_path=SESSION_DIR, properties=session_props)
    crate.add_dataset(dest_path=RESULTS_DIR, properties={
        "name": f"results of session {session_id} (outputs)",
        "description": f"Everything the workflow wrote under results/{session_id}/ (results contract 1).",
        "hasPart": output_refs,
    })

    run_id = f"#run-{session_id}"
    run: dict[str, Any] = {
        "name": f"huefringe workflow run on session {session_id}",
        "description": "Inputs are the object (session/ and config.yaml); outputs are the result (results/).",
        "actionStatus": "http://schema.org/CompletedActionStatus",  # a string, as Process Run Crate writes it
        "object": [_ref(SESSION_DIR)] + ([config_ref] if config_ref else []),
        "result": _ref(RESULTS_DIR),
        # the same deterministic date as datePublished: the clock would make archives differ
        "endTime": _end_time(date_published),
    }
    if instrument:
        run["instrument"] = instrument
    if author_ref:
        run["agent"] = author_ref
    entity(run_id, "CreateAction", run)

    description = (
        f"Capture session '{session_id}' (format {session_format}, folder session/) and what the "
        "huefringe workflow computed from it (results contract 1, folder results/), with the "
        "configuration used (config.yaml). Every file is listed with its SHA-256 checksum; "
        "check with: huefringe verify <archive>."
    )
    if prov.get("simulated"):
        description += " The capture session was written by a virtual bench: SIMULATED data, not a measurement."
    if date_note:
        description += f" datePublished: {date_note}."
    root = crate.root_dataset
    root["name"] = f"huefringe session {session_id}: capture session and results"
    root["description"] = description
    root["identifier"] = session_id
    root["datePublished"] = date_published
    root["license"] = license_ref
    root["publisher"] = publisher_ref
    if author_ref:
        root["author"] = author_ref
    root["conformsTo"] = profile_ref
    root["mentions"] = {"@id": run_id}
    root["hasPart"] = ([config_ref] if config_ref else []) + [_ref(SESSION_DIR), _ref(RESULTS_DIR)]
    if prov.get("simulated"):
        root["keywords"] = ["simulated data", "fringe projection", "metrology"]
    return crate.metadata.generate()
