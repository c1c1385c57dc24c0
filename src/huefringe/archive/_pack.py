"""Writing an archive: one deterministic ZIP of a session, its results and their crate."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import zipfile
from collections.abc import Mapping
from pathlib import Path, PurePosixPath
from typing import Any

from huefringe.io import atomic_path
from huefringe.settings import software_identity

from ._crate import _config_bytes, _date_published, _software, build_crate
from ._members import (
    _CHUNK,
    _STORED_SUFFIXES,
    CONFIG_NAME,
    METADATA_NAME,
    RESULTS_DIR,
    SESSION_DIR,
    ZIP_EPOCH,
    ArchiveError,
    _bytes_member,
    _file_member,
    _files_under,
    _Member,
)


def _session_meta(session: Path) -> dict[str, Any]:
    """session.yaml of a capture session, or of a structured-light session (checked whole: every
    file it lists present, none altered, so that the archive holds what the results came from)."""
    from huefringe.session import SessionError, read_meta
    from huefringe.session import SL_FORMAT, load_sl_session, session_format

    if session_format(session) == SL_FORMAT:
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
