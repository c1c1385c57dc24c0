"""Archives of a run: a capture session and its results in one ZIP file with RO-Crate metadata.

Layout of ``results/<id>.archive.zip`` (an attached RO-Crate 1.1 package, zipped)::

    ro-crate-metadata.json    RO-Crate JSON-LD (first member)
    config.yaml               the workflow configuration used (when given)
    session/...               every file of the capture-session folder (the inputs)
    results/...               every file of results/<id>/ (the outputs)

The crate is built with ``rocrate`` (ro-crate-py) and conforms to RO-Crate 1.1 and the Process
Run Crate profile 0.5 (``https://w3id.org/ro/wfrun/process/0.5``: one action, the workflow run,
with the software that ran it, its inputs and its outputs; the Snakefile itself is not packed,
so Workflow Run Crate does not fit). ``ro-crate-metadata.json`` holds the metadata descriptor,
the root dataset ``./`` (``name``, ``description``, ``identifier`` = the session id,
``datePublished``, ``license``, ``author``, ``publisher``, ``conformsTo`` the profile,
``mentions`` the run, ``hasPart``), the datasets ``session/`` (``dateCreated``, ``creator`` and
the description from the session's ``provenance`` block) and ``results/`` with ``hasPart``
listing their files, one ``File`` entity per file (``sha256``, ``contentSize`` in bytes,
``encodingFormat``), the licence, author, affiliation and publisher (an ``Organization``) as
contextual entities from the configuration's ``archive`` keys, one ``SoftwareApplication`` per
distribution (huefringe, Python and huefringe's runtime requirements, with ``version`` and
``url``), and the ``CreateAction`` ``#run-<id>`` whose ``object`` is the inputs (``session/``
and ``config.yaml``), whose ``result`` is ``results/`` (one value), whose ``instrument`` is
huefringe and whose ``agent`` is the author. ``sha256`` is the Workflow Run Crate term
``https://w3id.org/ro/terms/workflow-run#sha256``, added to the context.

Deterministic: the same files (same bytes, same relative paths), configuration and software
give the same archive bytes. Members are sorted, every timestamp is 1980-01-01 00:00:00 (the
ZIP epoch), permissions are fixed (0644), the JSON is written by this module from the
``rocrate`` document (entities in insertion order, fixed indentation), and ``datePublished``
is the session's ``provenance.captured_at`` when given, else ``SOURCE_DATE_EPOCH`` (the
reproducible-builds convention), else the ZIP epoch with the root's description saying it is a
placeholder: the clock and file modification times never enter the archive. The run's
``endTime`` is the same date (in the ``+00:00`` form the profile checks): the end of a run is
neither an input nor an output, and only a date the inputs give keeps archives of the same
inputs byte-identical. huefringe's SoftwareApplication has the absolute ``@id`` and ``url`` of
``[project.urls]`` ``Homepage`` in ``pyproject.toml`` (read from the installed distribution,
:func:`huefringe.settings.software_identity`), unless ``archive.software_url`` overrides it. The archive is written atomically
(:func:`huefringe.io.atomic_path`). Leftover temporary files of interrupted atomic writes
(``.<stem>.<random>.part<suffix>``) are not packed.

:func:`verify_archive` re-reads every member against the crate and names each altered
(checksum, size or unreadable data), missing (listed, absent) or unlisted (present, not listed)
file; ``huefringe verify ARCHIVE`` prints that and exits 1 on any problem. It accepts the ZIP
file or an extracted crate folder.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import importlib.metadata
import json
import os
import re
import stat
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import quote, unquote

import yaml

from huefringe.io import atomic_path, sha256_file, source_date_epoch
from huefringe.report import software_versions
from huefringe.settings import software_identity

__all__ = [
    "ArchiveError",
    "CONFORMS_TO",
    "CONTEXT",
    "METADATA_NAME",
    "Verification",
    "archive_index",
    "build_crate",
    "encoding_format",
    "is_partial_file",
    "read_crate",
    "verify_archive",
    "write_archive",
]

METADATA_NAME = "ro-crate-metadata.json"
#: Process Run Crate 0.5 is a profile of RO-Crate 1.1 (the validator checks conformsTo 1.1)
RO_CRATE_VERSION = "1.1"
CONFORMS_TO = f"https://w3id.org/ro/crate/{RO_CRATE_VERSION}"
PROCESS_RUN_PROFILE = "https://w3id.org/ro/wfrun/process/0.5"
SHA256_TERM = "https://w3id.org/ro/terms/workflow-run#sha256"
EXTRA_TERMS: dict[str, str] = {"sha256": SHA256_TERM}
CONTEXT: list[Any] = [f"{CONFORMS_TO}/context", EXTRA_TERMS]
CONFIG_NAME = "config.yaml"
SESSION_DIR = "session/"
RESULTS_DIR = "results/"
ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
DEFAULT_LICENSE = "Not specified by huefringe: the data owner's terms apply."

#: Media types by suffix (fixed table: ``mimetypes`` depends on the machine's configuration).
MEDIA_TYPES: dict[str, str] = {
    ".png": "image/png",
    ".tif": "image/tiff",
    ".tiff": "image/tiff",
    ".json": "application/json",
    ".yaml": "application/yaml",
    ".yml": "application/yaml",
    ".html": "text/html",
    ".htm": "text/html",
    ".stl": "model/stl",
    ".ply": "model/x-ply",
    ".npy": "application/x-npy",
    ".npz": "application/zip",
    ".zip": "application/zip",
    ".csv": "text/csv",
    ".md": "text/markdown",
    ".txt": "text/plain",
    ".log": "text/plain",
}
_STORED_SUFFIXES = frozenset({".png", ".npz", ".zip", ".gz", ".xz", ".bz2", ".jpg", ".jpeg"})
_PARTIAL_RE = re.compile(r"^\..+\.part(\.[^./]+)?$")
_CHUNK = 1 << 20


class ArchiveError(ValueError):
    """An archive cannot be written or read; the message names the file concerned."""


def encoding_format(name: str) -> str:
    """Media type recorded as ``encodingFormat`` for a file name (by suffix)."""
    return MEDIA_TYPES.get(PurePosixPath(name).suffix.lower(), "application/octet-stream")


def is_partial_file(name: str) -> bool:
    """True for a leftover temporary file of :func:`huefringe.io.atomic_path`."""
    return bool(_PARTIAL_RE.match(PurePosixPath(name).name))


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Member:
    name: str  # path inside the archive (POSIX)
    source: Path | None  # file on disk, or None for generated content
    data: bytes | None  # generated content
    size: int
    sha256: str


def _files_under(folder: Path) -> list[tuple[str, Path]]:
    """(relative POSIX path, path) of every regular file under ``folder``, sorted, partials skipped."""
    out = []
    for dirpath, dirnames, filenames in os.walk(folder, followlinks=False):
        dirnames.sort()
        for fn in sorted(filenames):
            p = Path(dirpath) / fn
            rel = p.relative_to(folder).as_posix()
            if is_partial_file(rel):
                continue
            try:
                mode = p.stat().st_mode  # follows a symlink to a file
            except OSError as exc:
                raise ArchiveError(f"{p}: cannot read ({exc})") from exc
            if stat.S_ISREG(mode):
                out.append((rel, p))
    return sorted(out)


def _file_member(name: str, path: Path) -> _Member:
    try:
        return _Member(name, path, None, path.stat().st_size, sha256_file(path))
    except OSError as exc:
        raise ArchiveError(f"{path}: cannot read ({exc})") from exc


def _bytes_member(name: str, data: bytes) -> _Member:
    return _Member(name, None, data, len(data), hashlib.sha256(data).hexdigest())


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


def _session_meta(session: Path) -> dict[str, Any]:
    """session.yaml of a capture session, or of a structured-light session (checked whole: every
    file it lists present, none altered, so that the archive holds what the results came from)."""
    from huefringe.session import SessionError, read_meta
    from huefringe.slsession import FORMAT, load_sl_session, session_format

    if session_format(session) == FORMAT:
        try:
            return load_sl_session(session).meta
        except SessionError as exc:
            raise ArchiveError(f"cannot archive {session}: not a valid structured-light session:\n{exc}") from exc
    try:
        return read_meta(session)
    except SessionError as exc:
        raise ArchiveError(f"cannot archive {session}: not a valid capture session:\n{exc}") from exc


def _zipinfo(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=ZIP_EPOCH)
    info.create_system = 3  # Unix, whatever the platform
    info.external_attr = (stat.S_IFREG | 0o644) << 16
    stored = PurePosixPath(name).suffix.lower() in _STORED_SUFFIXES  # already compressed
    info.compress_type = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
    return info


def write_archive(
    session: str | os.PathLike[str],
    results: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    config: Mapping[str, Any] | None = None,
    license: Mapping[str, str] | str | None = None,
    author: Mapping[str, str] | None = None,
    publisher: Mapping[str, str] | None = None,
) -> Path:
    """Pack a session folder and its results folder into one ZIP with RO-Crate metadata.

    Parameters
    ----------
    session : path
        The capture-session folder (its ``session.yaml`` must be readable), or a
        structured-light session (validated whole); its ``id`` names the crate.
    results : path
        The session's results folder, ``results/<id>/`` (its name must be the session id).
    out : path
        The archive to write (atomically), e.g. ``results/<id>.archive.zip``; it may not lie
        inside ``session`` or ``results``.
    config : mapping, optional
        The workflow configuration used, stored as ``config.yaml``.
    license, author, publisher : mapping, optional
        Contextual entities of the crate (see :func:`build_crate`); by default the
        configuration's ``archive`` keys (``workflow/schemas/config.schema.yaml``). Without
        either, the licence is a local entity saying it is not specified and the publisher an
        Organization saying the same.

    Returns
    -------
    Path
        ``out``.

    Raises
    ------
    ArchiveError
        Invalid session.yaml, results folder missing or named differently from the session id,
        a file that cannot be read or that changes while it is packed.
    """
    session, results, out = Path(session), Path(results), Path(out)
    meta = _session_meta(session)
    sid = str(meta["id"])
    provenance = dict(meta.get("provenance") or {})
    archive_cfg = dict((config or {}).get("archive") or {})
    license = license if license is not None else archive_cfg.get("license")
    author = author if author is not None else archive_cfg.get("author")
    publisher = publisher if publisher is not None else archive_cfg.get("publisher")
    software_url = software_identity(archive_cfg.get("software_url")).url
    if not results.is_dir():
        raise ArchiveError(f"{results}: results folder does not exist (run the workflow first)")
    if results.resolve().name != sid:
        raise ArchiveError(f"{results}: results folder of session '{sid}' must be named '{sid}'")
    for folder in (session, results):
        if out.resolve().is_relative_to(folder.resolve()):
            raise ArchiveError(f"{out}: the archive may not be written inside {folder}")
    inputs = [_file_member(SESSION_DIR + rel, p) for rel, p in _files_under(session)]
    outputs = [_file_member(RESULTS_DIR + rel, p) for rel, p in _files_under(results)]
    cfg = _bytes_member(CONFIG_NAME, _config_bytes(config)) if config is not None else None
    date, note = _date_published(provenance)
    crate = build_crate(sid, inputs, outputs, cfg, _software(), date_published=date, date_note=note,
                        license=license, author=author, publisher=publisher, provenance=provenance,
                        software_url=software_url, session_format=str(meta.get("format") or "capture-session/1"))
    meta = _bytes_member(METADATA_NAME, (json.dumps(crate, indent=2, ensure_ascii=False) + "\n").encode("utf-8"))
    members = [meta] + sorted(([cfg] if cfg else []) + inputs + outputs, key=lambda m: m.name)
    with atomic_path(out) as tmp:
        with zipfile.ZipFile(tmp, "w", allowZip64=True) as zf:
            for m in members:
                _write_member(zf, m)
    return out


def _write_member(zf: zipfile.ZipFile, m: _Member) -> None:
    info = _zipinfo(m.name)
    if m.data is not None:
        zf.writestr(info, m.data)
        return
    assert m.source is not None
    info.file_size = m.size
    h = hashlib.sha256()
    size = 0
    try:
        with open(m.source, "rb") as src, zf.open(info, "w") as dst:
            while block := src.read(_CHUNK):
                h.update(block)
                size += len(block)
                dst.write(block)
    except OSError as exc:
        raise ArchiveError(f"{m.source}: cannot read ({exc})") from exc
    if size != m.size or h.hexdigest() != m.sha256:
        raise ArchiveError(f"{m.source}: the file changed while it was being archived; run again when nothing writes to it")


# --------------------------------------------------------------------------------------------
# reading and verifying
# --------------------------------------------------------------------------------------------


@dataclass
class Verification:
    """Outcome of :func:`verify_archive`."""

    archive: Path
    problems: list[str] = field(default_factory=list)
    files: int = 0
    """File entities checked."""
    inputs: int = 0
    outputs: int = 0
    session: str | None = None

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> str:
        if self.ok:
            return (
                f"OK: {self.archive}: {self.files} files match their sha256 in {METADATA_NAME} "
                f"(session '{self.session}': {self.inputs} inputs, {self.outputs} outputs)"
            )
        lines = [f"FAILED: {self.archive}: {len(self.problems)} problem(s):"]
        lines += [f"  - {p}" for p in self.problems]
        return "\n".join(lines)


class _Reader:
    """Uniform access to the members of a ZIP crate or of an extracted crate folder."""

    def __init__(self, path: Path):
        self.path = path
        self.zip: zipfile.ZipFile | None = None
        self.duplicates: list[str] = []
        if path.is_dir():
            self._names = [rel for rel, _ in _files_under(path)]
        else:
            try:
                self.zip = zipfile.ZipFile(path)
            except FileNotFoundError as exc:
                raise ArchiveError(f"{path}: no such file") from exc
            except (zipfile.BadZipFile, OSError, EOFError, ValueError) as exc:
                raise ArchiveError(f"{path}: not a readable ZIP archive ({exc})") from exc
            seen: set[str] = set()
            names = []
            for info in self.zip.infolist():
                if info.is_dir():
                    continue
                if info.filename in seen:
                    self.duplicates.append(info.filename)
                    continue
                seen.add(info.filename)
                names.append(info.filename)
            self._names = names

    def names(self) -> list[str]:
        return list(self._names)

    def read_bytes(self, name: str) -> bytes:
        if self.zip is not None:
            return self.zip.read(name)
        return (self.path / name).read_bytes()

    def chunks(self, name: str) -> Iterator[bytes]:
        if self.zip is not None:
            with self.zip.open(name) as fh:
                while block := fh.read(_CHUNK):
                    yield block
        else:
            with open(self.path / name, "rb") as fh:
                while block := fh.read(_CHUNK):
                    yield block

    def close(self) -> None:
        if self.zip is not None:
            self.zip.close()


def _as_list(x: Any) -> list[Any]:
    if x is None:
        return []
    return list(x) if isinstance(x, list) else [x]


def read_crate(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``ro-crate-metadata.json`` document of an archive (ZIP file or crate folder)."""
    reader = _Reader(Path(path))
    try:
        return _load_crate(reader)
    finally:
        reader.close()


def _load_crate(reader: _Reader) -> dict[str, Any]:
    if METADATA_NAME not in reader.names():
        raise ArchiveError(f"{reader.path}: no {METADATA_NAME} at the archive root: not an RO-Crate")
    try:
        doc = json.loads(reader.read_bytes(METADATA_NAME).decode("utf-8"))
    except (ValueError, UnicodeDecodeError, zipfile.BadZipFile, zlib.error, OSError, EOFError) as exc:
        raise ArchiveError(f"{reader.path}: {METADATA_NAME} is damaged or not JSON ({exc})") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("@graph"), list):
        raise ArchiveError(f"{reader.path}: {METADATA_NAME} has no @graph list: not RO-Crate JSON-LD")
    return doc


def _types(entity: Mapping[str, Any]) -> list[str]:
    return [str(t) for t in _as_list(entity.get("@type"))]


def _member_name(entity_id: str) -> str:
    return unquote(entity_id)


def _unsafe(name: str) -> bool:
    p = PurePosixPath(name)
    return p.is_absolute() or ".." in p.parts or "\\" in name


def verify_archive(path: str | os.PathLike[str]) -> Verification:
    """Check every file of an archive against the sha256 and size listed in its RO-Crate.

    Parameters
    ----------
    path : path
        An archive from :func:`write_archive`, or the folder it was extracted into.

    Returns
    -------
    Verification
        ``problems`` names each file that is altered (sha256 or size differ, or its data cannot
        be read back), missing (listed in the crate, absent), unlisted (present, not listed) or
        duplicated, and any structural problem of the crate; empty when everything matches.

    Raises
    ------
    ArchiveError
        The archive cannot be opened or has no readable ``ro-crate-metadata.json``.
    """
    path = Path(path)
    reader = _Reader(path)
    try:
        doc = _load_crate(reader)
        return _verify(reader, doc)
    finally:
        reader.close()


def _verify(reader: _Reader, doc: Mapping[str, Any]) -> Verification:
    res = Verification(reader.path)
    graph = [e for e in doc["@graph"] if isinstance(e, Mapping)]
    by_id = {str(e.get("@id")): e for e in graph}
    descriptor = by_id.get(METADATA_NAME)
    conforms = descriptor.get("conformsTo") if descriptor else None
    conforms_ids = [c.get("@id") if isinstance(c, Mapping) else c for c in _as_list(conforms)]
    if descriptor is None or not any(str(c).startswith("https://w3id.org/ro/crate/") for c in conforms_ids):
        res.problems.append(f"{METADATA_NAME}: no metadata descriptor conforming to an RO-Crate version")
    root_id = "./"
    if descriptor is not None and isinstance(descriptor.get("about"), Mapping):
        root_id = str(descriptor["about"].get("@id", "./"))
    root = by_id.get(root_id)
    if root is None or "Dataset" not in _types(root):
        res.problems.append(f"{METADATA_NAME}: no root dataset '{root_id}'")
    else:
        res.session = str(root.get("identifier")) if root.get("identifier") is not None else None

    def parts(dataset_id: str) -> set[str]:
        d = by_id.get(dataset_id, {})
        return {_member_name(str(r.get("@id"))) for r in _as_list(d.get("hasPart")) if isinstance(r, Mapping)}

    input_names, output_names = parts(SESSION_DIR), parts(RESULTS_DIR)
    listed: dict[str, Mapping[str, Any]] = {}
    for e in graph:
        if "File" not in _types(e):
            continue
        eid = str(e.get("@id", ""))
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", eid):
            continue  # a web resource, not a member
        name = _member_name(eid)
        if name in listed:
            res.problems.append(f"{name}: listed twice in {METADATA_NAME}")
        listed[name] = e

    present = set(reader.names())
    for name in reader.duplicates:
        res.problems.append(f"{name}: stored more than once in the archive")
    for name in sorted(listed):
        e = listed[name]
        if _unsafe(name):
            res.problems.append(f"{name}: unsafe path in {METADATA_NAME}")
            continue
        if name not in present:
            res.problems.append(f"{name}: missing (listed in {METADATA_NAME}, not in the archive)")
            continue
        want = str(e.get("sha256", "")).lower()
        if not re.fullmatch(r"[0-9a-f]{64}", want):
            res.problems.append(f"{name}: no valid sha256 in {METADATA_NAME}")
            continue
        h = hashlib.sha256()
        size = 0
        try:
            for block in reader.chunks(name):
                h.update(block)
                size += len(block)
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError) as exc:
            res.problems.append(f"{name}: altered (its data cannot be read back: {exc})")
            continue
        got = h.hexdigest()
        listed_size = e.get("contentSize")
        if got != want:
            res.problems.append(f"{name}: altered (sha256 {got} differs from {want} listed in {METADATA_NAME})")
        elif listed_size is not None and str(listed_size) != str(size):
            res.problems.append(f"{name}: altered ({size} bytes, {METADATA_NAME} lists {listed_size})")
        res.files += 1
    for name in sorted(present - set(listed) - {METADATA_NAME}):
        res.problems.append(f"{name}: unlisted (in the archive, not in {METADATA_NAME})")
    res.inputs = len(input_names & set(listed))
    res.outputs = len(output_names & set(listed))
    for name in sorted(set(listed) - input_names - output_names - {CONFIG_NAME}):
        res.problems.append(f"{name}: listed as a File but not part of session/ or results/")
    return res


def archive_index(archives: list[str | os.PathLike[str]]) -> dict[str, Any]:
    """The index of a run's archives: for each, its session, size, SHA-256 and crate summary.

    What ``results/archives.json`` holds (rule ``archive``): a lab moving the archives elsewhere
    checks each ZIP as a whole against it (``sha256sum``) before ``huefringe verify`` checks the
    files inside.

    Parameters
    ----------
    archives : list of path
        Archives written by :func:`write_archive`.

    Returns
    -------
    dict
        ``{"archives": [{"file", "session", "bytes", "sha256", "date_published", "files",
        "inputs", "outputs"}, ...]}`` in the order given; ``file`` is the archive's name,
        ``files`` the File entities of its crate, ``inputs``/``outputs`` those under
        ``session/`` and ``results/``.

    Raises
    ------
    ArchiveError
        An archive cannot be read or has no RO-Crate (the message names it).
    """
    rows = []
    for path in map(Path, archives):
        doc = read_crate(path)
        by_id = {str(e.get("@id")): e for e in doc["@graph"] if isinstance(e, Mapping)}
        root = by_id.get("./", {})
        n_files = sum("File" in _types(e) for e in by_id.values())
        try:
            size, digest = path.stat().st_size, sha256_file(path)
        except OSError as exc:
            raise ArchiveError(f"{path}: cannot read ({exc})") from exc
        rows.append({
            "file": path.name,
            "session": root.get("identifier"),
            "bytes": size,
            "sha256": digest,
            "date_published": root.get("datePublished"),
            "files": n_files,
            "inputs": len(_as_list(by_id.get(SESSION_DIR, {}).get("hasPart"))),
            "outputs": len(_as_list(by_id.get(RESULTS_DIR, {}).get("hasPart"))),
        })
    return {"archives": rows}
