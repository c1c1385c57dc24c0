# Height maps (with QA, and the phase and hue maps of the rendered frames, or of all with
# measurement.maps: all), point clouds and the three-step baseline, in batches of frames per job
# (one rule per session and batch, a multiple of measurement.parallel_jobs, at most frames_per_job frames:
# plan.batch_frames; a 1000-frame session costs 4 job start-ups, not 1000). The
# clouds and the X3P files are jobs of their own (cloud_frames_*, x3p_frames_*), made from the
# batch's height maps, so that the height maps do not wait for them.
# Resources: config `resources: {measure_frames: {mem_mb: ..., runtime: ...}}` (also cloud_frames,
# x3p_frames, baseline_frames), or --set-resources on the generated rule names.
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/measurement.smk).

# Why a loop: one batch job writes one file per frame, and a rule's outputs must be patterns of its
# wildcards, so a {batch} wildcard cannot name them; `directory()` would hide the per-frame files
# from mesh/render/metrology, and `group:` would still make one rule instance per frame.
for _sid, _plan in PLANS.items():
    for _b, _frames in enumerate(_plan.batches):

        rule:
            name:
                f"measure_frames_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                camera_json=R(_sid, "calib", "camera.json"),
                table=R(_sid, "calib", "table_object.json"),
                model=R(_sid, "calib", "phase_to_height.npz"),
            output:
                **measure_outputs(_sid, _frames),
            log:
                f"logs/{_sid}/measure_{_b:03d}.log",
            conda:
                "../envs/huefringe.yaml"
            threads: 1
            resources:
                **rule_resources(
                    "measure_frames", mem_mb=3000, runtime=max(10, len(_frames) // 10)
                ),
            params:
                session=str(_plan.path),
                frames=_frames,
                map_frames=[n for n in _frames if n in set(map_frames(_sid))],
                hue_model=config["hue_model"],
                measurement=config["measurement"],
                calibration=config["calibration"],
            script:
                "../../scripts/measure_frames.py"

        rule:
            name:
                f"cloud_frames_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                camera_json=R(_sid, "calib", "camera.json"),
                heights=frame_outputs(_sid, _frames)["heights"],
                uncertainties=frame_outputs(_sid, _frames)["uncertainties"],
            output:
                clouds=frame_outputs(_sid, _frames)["clouds"],
            log:
                f"logs/{_sid}/cloud_{_b:03d}.log",
            conda:
                "../envs/huefringe.yaml"
            threads: 1
            resources:
                **rule_resources(
                    "cloud_frames", mem_mb=2000, runtime=max(10, len(_frames) // 10)
                ),
            params:
                session=str(_plan.path),
                frames=_frames,
            script:
                "../../scripts/cloud_frames.py"

        _x3p = [n for n in _frames if n in set(x3p_selection(_sid))]
        if _x3p:  # the batch's frames selected by x3p.frames

            rule:
                name:
                    f"x3p_frames_{_sid.replace('-', '_')}_{_b:03d}"
                input:
                    heights=frame_outputs(_sid, _x3p)["heights"],
                output:
                    x3p=frame_outputs(_sid, _x3p)["x3p"],
                log:
                    f"logs/{_sid}/x3p_{_b:03d}.log",
                conda:
                    "../envs/huefringe.yaml"
                threads: 1
                resources:
                    **rule_resources(
                        "x3p_frames", mem_mb=1000, runtime=max(10, len(_x3p) // 20)
                    ),
                params:
                    session=str(_plan.path),
                    frames=_x3p,
                script:
                    "../../scripts/x3p_frames.py"

    for _b, _frames in enumerate(_plan.phase_shift_batches):

        rule:
            name:
                f"baseline_frames_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                camera_json=R(_sid, "calib", "camera.json"),
                model=R(_sid, "calib", "phase_to_height.npz"),
                object_table=R(_sid, "calib", "table_object.json"),
            output:
                **baseline_outputs(_sid, _frames),
            log:
                f"logs/{_sid}/baseline_{_b:03d}.log",
            conda:
                "../envs/huefringe.yaml"
            threads: 1
            resources:
                **rule_resources(
                    "baseline_frames", mem_mb=2000, runtime=max(10, len(_frames) // 10)
                ),
            params:
                session=str(_plan.path),
                frames=_frames,
                measurement=config["measurement"],
            script:
                "../../scripts/baseline_frames.py"


rule accuracy_report:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        heights=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["heights"],
        baseline=lambda w: baseline_outputs(w.sid, PLANS[w.sid].phase_shift)["heights"],
        uncertainties=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)[
            "uncertainties"
        ],
    output:
        report=R("{sid}", "accuracy.json"),
        reliability=R("{sid}", "metrology", "reliability.png"),
    log:
        "logs/{sid}/accuracy.log",
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        session=session_dir,
        measurement=config["measurement"],
    script:
        "../../scripts/accuracy_report.py"
