# Session check, camera corrections (X, Y model, channel registration: calib/camera.json),
# per-pixel hue tables, plane calibration and the compensated pattern (paper Fig. 6).
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/calibration.smk).


rule check_session:
    input:
        session_yaml,
    output:
        summary=R("{sid}", "qa", "session_check.json"),
    log:
        "logs/{sid}/check_session.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        session=session_dir,
    script:
        "../../scripts/check_session.py"


rule camera_calibration:
    input:
        R("{sid}", "qa", "session_check.json"),  # order only: the session passed its deep check
    output:
        record=R("{sid}", "calib", "camera.json"),
    log:
        "logs/{sid}/camera_calibration.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        session=session_dir,
        camera=config["camera"],
        calibration=config["calibration"],
    script:
        "../../scripts/camera_calibration.py"


rule hue_table:
    input:
        R("{sid}", "qa", "session_check.json"),  # order only: the session passed its deep check
        camera_json=R("{sid}", "calib", "camera.json"),
    output:
        R("{sid}", "calib", "table_{which}.npy"),  # written by HueTable.save beside the table
        R("{sid}", "calib", "table_{which}.maps.npz"),
        table=R("{sid}", "calib", "table_{which}.json"),
        stats=R("{sid}", "calib", "table_{which}.stats.json"),
    log:
        "logs/{sid}/hue_table_{which}.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        session=session_dir,
        hue_model=config["hue_model"],
        calibration=config["calibration"],
    script:
        "../../scripts/hue_table.py"


rule plane_calibration:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        table=R("{sid}", "calib", "table_reference.json"),
        object_table=R("{sid}", "calib", "table_object.json"),  # the texture-blur estimate (calibration.texture_blur_px2: auto)
    output:
        model=R("{sid}", "calib", "phase_to_height.npz"),
        stats=R("{sid}", "calib", "planes.json"),
        phase_error_table=R("{sid}", "calib", "phase_error.npz"),
        phase_error_summary=R("{sid}", "calib", "phase_error.json"),
        phase_error_figure=report(
            R("{sid}", "calib", "phase_error.png"),
            caption="../report/phase_error.rst",
            category="Calibration",
        ),
    log:
        "logs/{sid}/plane_calibration.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        session=session_dir,
        hue_model=config["hue_model"],
        calibration=config["calibration"],
    script:
        "../../scripts/plane_calibration.py"


rule compensation:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        table=R("{sid}", "calib", "table_reference.json"),
        model=R("{sid}", "calib", "phase_to_height.npz"),
    output:
        pattern=R("{sid}", "calib", "compensated_pattern.png"),
        history=R("{sid}", "calib", "compensation.json"),
        cross_section=report(
            R("{sid}", "calib", "qa_hue_cross_section.png"),
            caption="../report/hue_cross_section.rst",
            category="Calibration",
        ),
        residual_map=report(
            R("{sid}", "calib", "qa_residual_map.png"),
            caption="../report/residual_map.rst",
            category="Calibration",
        ),
    log:
        "logs/{sid}/compensation.log",
    priority: 10  # its cross-section figure is in the metrology report: see rule metrology
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        session=session_dir,
        hue_model=config["hue_model"],
        calibration=config["calibration"],
    script:
        "../../scripts/compensation.py"
