# Archives (not part of `all`): one ZIP per session holding the session folder, results/<id>/
# and the configuration used, with RO-Crate 1.1 metadata (ro-crate-metadata.json) listing every
# file with its sha256. Check one with: huefringe verify results/<id>.archive.zip
#   snakemake --cores 2 archive                          every planned session
#   snakemake --cores 2 results/<id>.archive.zip         one session


def session_results(sid):
    """Every declared result of session ``sid`` (the part of all_targets() under results/<sid>/)."""
    prefix = R(sid, "")
    return [p for p in all_targets() if p.startswith(prefix)]


rule archive_session:
    input:
        session=session_yaml,
        results=lambda w: session_results(w.sid),
    output:
        archive=f"{RESULTS}/{{sid}}.archive.zip",
    params:
        session=session_dir,
        results=lambda w: R(w.sid),
    log:
        "logs/{sid}/archive.log",
    threads: 1
    resources:
        mem_mb=1000,
        runtime=30,
    run:
        from huefringe.archive import ArchiveError, verify_archive, write_archive

        Path(log[0]).parent.mkdir(parents=True, exist_ok=True)
        try:
            write_archive(params.session, params.results, output.archive, config=config)
            check = verify_archive(output.archive)  # read back once: the archive is what it claims
            if not check.ok:
                raise ArchiveError(check.summary())
        except ArchiveError as exc:
            Path(log[0]).write_text(f"{exc}\n")
            sys.stderr.write(f"\nhuefringe: {exc}\n")
            raise
        Path(log[0]).write_text(check.summary() + "\n")


rule archive:
    input:
        [f"{RESULTS}/{sid}.archive.zip" for sid in PLANS],


localrules:
    archive,
