# Archives (not part of `all`): one ZIP per session holding the session folder, results/<id>/
# and the configuration used, with RO-Crate 1.1 metadata (ro-crate-metadata.json) listing every
# file with its sha256. Check one with: huefringe verify results/<id>.archive.zip
#   snakemake --cores 2 archive                          every planned session, and their index
#                                                        results/archives.json (size, sha256)
#   snakemake --cores 2 results/<id>.archive.zip         one session
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/archive.smk).


rule archive_session:
    input:
        session=session_yaml,
        results=lambda w: session_results(w.sid),
    output:
        archive=f"{RESULTS}/{{sid}}.archive.zip",
    log:
        "logs/{sid}/archive.log",
    wildcard_constraints:
        sid=ANY_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=30,
    params:
        session=session_dir,
        results=lambda w: R(w.sid),
        config=config,
    script:
        "../../scripts/archive_session.py"


rule archive:
    input:
        archives=[
            f"{RESULTS}/{sid}.archive.zip" for sid in PLANS if sid not in TABLE1_IDS
        ],
    output:
        index=f"{RESULTS}/archives.json",
    log:
        "logs/archive.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=10,
    script:
        "../../scripts/archive.py"
