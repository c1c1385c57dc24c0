# Step-height metrology: report.json (results contract) and the self-contained report.html.
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/metrology.smk).


rule metrology:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        heights=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["heights"],
        qa=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["qa"],
        uncertainties=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)[
            "uncertainties"
        ],
        supports=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["supports"],
        model=R("{sid}", "calib", "phase_to_height.npz"),
        object_table=R("{sid}", "calib", "table_object.json"),
        baseline=lambda w: baseline_outputs(w.sid, PLANS[w.sid].phase_shift)["heights"],
        planes=R("{sid}", "calib", "planes.json"),
        tables=R("{sid}", "calib", "table_object.stats.json"),
        cross_section=R("{sid}", "calib", "qa_hue_cross_section.png"),
        render=lambda w: render_outputs(w.sid, PLANS[w.sid].frames[0])[0],
        height_map=lambda w: render_outputs(w.sid, PLANS[w.sid].frames[0])[3],
        accuracy=lambda w: (
            [R(w.sid, "accuracy.json")] if PLANS[w.sid].ground_truth else []
        ),
    output:
        json=report(
            R("{sid}", "metrology", "report.json"),
            caption="../report/metrology.rst",
            category="Metrology",
        ),
        html=report(
            R("{sid}", "metrology", "report.html"),
            caption="../report/metrology_html.rst",
            category="Metrology",
        ),
        profile=report(
            R("{sid}", "metrology", "profile.png"),
            caption="../report/profile.rst",
            category="Metrology",
        ),
        per_frame=report(
            R("{sid}", "metrology", "per_frame.png"),
            caption="../report/per_frame.rst",
            category="Metrology",
        ),
    log:
        "logs/{sid}/metrology.log",
    # first among the jobs that are ready (with the mesh, render and compensation jobs it waits
    # for), on one core: the cloud jobs beside it are bound by the disk (8.7 MB of PLY per
    # 640 x 480 frame), so the report's CPU work runs in their shadow instead of after them on two
    # threads (1000-frame bench session, --cores 2, the default set after the heights: 49.5 / 53.7 s
    # -> 41.2 / 42.5 s, two runs each)
    priority: 10
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        session=session_dir,
        config=config,
    script:
        "../../scripts/metrology.py"


rule table1:
    input:
        reports=[R(sid, "metrology", "report.json") for sid in TABLE1_IDS],
    output:
        markdown=report(
            R("table1", "table1.md"),
            caption="../report/table1.rst",
            category="Table 1",
        ),
        csv=R("table1", "table1.csv"),
        uncertainty_ratio=R("table1", "uncertainty_ratio.json"),
        figure=report(
            R("table1", "table1.png"),
            caption="../report/table1.rst",
            category="Table 1",
        ),
    log:
        "logs/table1.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        periods=config.get("table1", {}).get("periods", []),
        step=config.get("table1", {}).get("step", "blue"),
        nominal_mm=config.get("table1", {}).get("nominal_mm", 1.0),
    script:
        "../../scripts/table1.py"
