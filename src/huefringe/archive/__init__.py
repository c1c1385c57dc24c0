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

The package's private modules: ``_members`` (layout constants, media types, the members of an
archive), ``_crate`` (the RO-Crate document), ``_pack`` (:func:`write_archive`, the ZIP) and
``_read`` (:func:`read_crate`, :func:`verify_archive`, :func:`archive_index`).
"""

from __future__ import annotations

from ._members import (  # noqa: F401
    METADATA_NAME,
    RO_CRATE_VERSION,
    CONFORMS_TO,
    PROCESS_RUN_PROFILE,
    SHA256_TERM,
    EXTRA_TERMS,
    CONTEXT,
    CONFIG_NAME,
    SESSION_DIR,
    RESULTS_DIR,
    ZIP_EPOCH,
    DEFAULT_LICENSE,
    MEDIA_TYPES,
    _STORED_SUFFIXES,
    _PARTIAL_RE,
    _CHUNK,
    ArchiveError,
    encoding_format,
    is_partial_file,
    _Member,
    _files_under,
    _file_member,
    _bytes_member,
)
from ._crate import (  # noqa: F401
    _date_published,
    _end_time,
    _runtime_requirements,
    _software,
    _ref,
    _config_bytes,
    _contextual_id,
    _entity,
    _organization,
    _author,
    _software_id,
    _add_software,
    _add_file,
    _provenance_sentences,
    build_crate,
)
from ._pack import (  # noqa: F401
    _session_meta,
    _zipinfo,
    write_archive,
    _write_member,
)
from ._read import (  # noqa: F401
    Verification,
    _Reader,
    _as_list,
    read_crate,
    _load_crate,
    _types,
    _member_name,
    _unsafe,
    verify_archive,
    _verify,
    archive_index,
)

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
