# Structured-light sessions (structured-light-session/1): the rig calibrated from a session's board
# poses, the captures decoded and triangulated on the camera grid, the height over the base plane,
# meshes, renders and the same metrology report as capture sessions (docs/rig.md).
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/rig.smk).


rule rig_calibrate:
    input:
        session=session_yaml,
    output:
        calibration=R("{sid}", "calib", "rig.yml"),
        report=R("{sid}", "calib", "rig.report.json"),
        jackknife=R("{sid}", "calib", "rig.jackknife.json"),
    log:
        "logs/{sid}/rig_calibrate.log",
    wildcard_constraints:
        sid=CALIBRATE_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_calibrate", mem_mb=3000, runtime=30),
    params:
        session=session_dir,
        config=config,
    script:
        "../../scripts/rig_calibrate.py"


rule rig_calibration_from:
    input:
        unpack(rig_calibration_source),
    output:
        calibration=R("{sid}", "calib", "rig.yml"),
        report=R("{sid}", "calib", "rig.report.json"),
        jackknife=R("{sid}", "calib", "rig.jackknife.json"),
    log:
        "logs/{sid}/rig_calibration_from.log",
    wildcard_constraints:
        sid=BORROW_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_calibration_from", mem_mb=500, runtime=5),
    script:
        "../../scripts/rig_calibration_from.py"


rule rig_measure:
    input:
        session=session_yaml,
        calibration=rig_calibration,
        jackknife=rig_jackknife,
    output:
        xyz=R("{sid}", "xyz", "frame_0000.tiff"),
        xyz_sigma=R("{sid}", "xyz", "frame_0000_sigma.tiff"),
        xyz_u=R("{sid}", "xyz", "frame_0000_u.tiff"),
        decoded=R("{sid}", "decode", "frame_0000.tiff"),
        cloud=R("{sid}", "cloud", "frame_0000.ply"),
        height=R("{sid}", "height", "frame_0000.tiff"),
        uncertainty=R("{sid}", "uncertainty", "frame_0000.tiff"),
        x3p=R("{sid}", "x3p", "frame_0000.x3p"),
        qa=R("{sid}", "qa", "frames", "frame_0000.json"),
        quality=R("{sid}", "qa", "frame_0000_decode.png"),
    log:
        "logs/{sid}/rig_measure.log",
    wildcard_constraints:
        sid=CODED_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_measure", mem_mb=4000, runtime=30),
    params:
        session=session_dir,
        config=config,
    script:
        "../../scripts/rig_measure.py"


# A session with one-shot frames (trapezoid blocks): one job measures them frame after frame (the
# coded blocks decoded once as the order reference, or those of the reference session it names,
# whose files are inputs; the hue table from the bands) into the files
# rig_measure writes, one set per frame; a rule per session, as the frame count names its outputs.
for _sid in ONESHOT_IDS:

    rule:
        name:
            f"rig_oneshot_{_sid.replace('-', '_')}"
        input:
            session=str(Path(session_dir(_sid)) / "session.yaml"),
            calibration=rig_calibration(_sid),
            jackknife=rig_jackknife(_sid),
            reference=oneshot_reference_inputs(_sid),
        output:
            **oneshot_outputs(_sid),
        log:
            f"logs/{_sid}/rig_oneshot.log",
        conda:
            "../envs/huefringe.yaml"
        threads: 1
        resources:
            **rule_resources(
                "rig_oneshot", mem_mb=4000, runtime=max(30, PLANS[_sid].oneshot_frames)
            ),
        params:
            session=lambda w, input: str(Path(input.session).parent),
            config=config,
        script:
            "../../scripts/rig_oneshot.py"


rule rig_surfaces:
    input:
        session=session_yaml,
        height=R("{sid}", "height", "frame_0000.tiff"),
        uncertainty=R("{sid}", "uncertainty", "frame_0000.tiff"),
    output:
        ply=R("{sid}", "mesh", "frame_0000.ply"),
        stl=R("{sid}", "mesh", "frame_0000.stl"),
        stats=R("{sid}", "mesh", "frame_0000.stats.json"),
        top=R("{sid}", "renders", "frame_0000_top.png"),
        oblique1=R("{sid}", "renders", "frame_0000_oblique1.png"),
        oblique2=R("{sid}", "renders", "frame_0000_oblique2.png"),
        height_map=R("{sid}", "renders", "frame_0000_height.png"),
        uncertainty_map=R("{sid}", "renders", "frame_0000_uncertainty.png"),
    log:
        "logs/{sid}/rig_surfaces.log",
    wildcard_constraints:
        sid=RIG_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_surfaces", mem_mb=3000, runtime=10),
    params:
        session=session_dir,
        mesh=config["mesh"],
        render=config["render"],
    script:
        "../../scripts/rig_surfaces.py"


rule rig_metrology:
    input:
        session=session_yaml,
        calibration=rig_calibration,
        jackknife=rig_jackknife,
        calibration_report=rig_calibration_report,
        reference=lambda w: oneshot_reference_inputs(w.sid),
        xyz=rig_report_frames("xyz"),
        xyz_sigma=rig_report_frames("xyz_sigma"),
        decoded=rig_report_frames("decoded"),
        qa=rig_report_frames("qa"),
        quality=R("{sid}", "qa", "frame_0000_decode.png"),
        render=R("{sid}", "renders", "frame_0000_top.png"),
        height_map=R("{sid}", "renders", "frame_0000_height.png"),
    output:
        json=R("{sid}", "metrology", "report.json"),
        html=R("{sid}", "metrology", "report.html"),
    log:
        "logs/{sid}/rig_metrology.log",
    wildcard_constraints:
        sid=RIG_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_metrology", mem_mb=3000, runtime=10),
    params:
        session=session_dir,
        config=config,
    script:
        "../../scripts/rig_metrology.py"


rule rig_accuracy:
    input:
        session=session_yaml,
        calibration=rig_calibration,
        xyz=R("{sid}", "xyz", "frame_0000.tiff"),
        xyz_sigma=R("{sid}", "xyz", "frame_0000_sigma.tiff"),
        xyz_u=R("{sid}", "xyz", "frame_0000_u.tiff"),
    output:
        accuracy=R("{sid}", "accuracy.json"),
    log:
        "logs/{sid}/rig_accuracy.log",
    wildcard_constraints:
        sid=RIG_SID,
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        **rule_resources("rig_accuracy", mem_mb=2000, runtime=10),
    params:
        session=session_dir,
    script:
        "../../scripts/rig_accuracy.py"
