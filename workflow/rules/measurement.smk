# Height maps (with QA, and the phase and hue maps of the rendered frames, or of all with
# measurement.maps: all), point clouds and the three-step baseline, in batches of frames per job
# (one rule per session and batch, so a 1000-frame session costs 4 job start-ups, not 1000). The
# clouds are jobs of their own (cloud_*), made from the batch's height maps, so that the height
# maps do not wait for them.

for _sid, _plan in PLANS.items():
    for _b, _frames in enumerate(_plan.batches):

        rule:
            name:
                f"measure_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                table=R(_sid, "calib", "table_object.json"),
                model=R(_sid, "calib", "phase_to_height.npz"),
            output:
                **measure_outputs(_sid, _frames),
            params:
                session=str(_plan.path),
                frames=_frames,
                map_frames=[n for n in _frames if n in set(map_frames(_sid))],
                hue_model=config["hue_model"],
                measurement=config["measurement"],
                calibration=config["calibration"],
            log:
                f"logs/{_sid}/measure_{_b:03d}.log",
            threads: 1
            resources:
                mem_mb=3000,
                runtime=max(10, len(_frames) // 10),
            conda:
                "../envs/huefringe.yaml"
            script:
                "../../scripts/measure_frames.py"

        rule:
            name:
                f"cloud_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                heights=frame_outputs(_sid, _frames)["heights"],
                uncertainties=frame_outputs(_sid, _frames)["uncertainties"],
            output:
                clouds=frame_outputs(_sid, _frames)["clouds"],
            params:
                session=str(_plan.path),
                frames=_frames,
            log:
                f"logs/{_sid}/cloud_{_b:03d}.log",
            threads: 1
            resources:
                mem_mb=2000,
                runtime=max(10, len(_frames) // 10),
            conda:
                "../envs/huefringe.yaml"
            script:
                "../../scripts/cloud_frames.py"

    _ps = _plan.phase_shift
    _per = config["measurement"]["frames_per_job"]
    for _b, _frames in enumerate([_ps[i : i + _per] for i in range(0, len(_ps), _per)]):

        rule:
            name:
                f"baseline_{_sid.replace('-', '_')}_{_b:03d}"
            input:
                model=R(_sid, "calib", "phase_to_height.npz"),
                object_table=R(_sid, "calib", "table_object.json"),
            output:
                **baseline_outputs(_sid, _frames),
            params:
                session=str(_plan.path),
                frames=_frames,
                measurement=config["measurement"],
            log:
                f"logs/{_sid}/baseline_{_b:03d}.log",
            threads: 1
            resources:
                mem_mb=2000,
                runtime=max(10, len(_frames) // 10),
            conda:
                "../envs/huefringe.yaml"
            script:
                "../../scripts/baseline_frames.py"


rule accuracy:
    input:
        heights=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["heights"],
        baseline=lambda w: baseline_outputs(w.sid, PLANS[w.sid].phase_shift)["heights"],
        uncertainties=lambda w: frame_outputs(w.sid, PLANS[w.sid].frames)["uncertainties"],
    output:
        report=R("{sid}", "accuracy.json"),
        reliability=R("{sid}", "metrology", "reliability.png"),
    params:
        session=session_dir,
        measurement=config["measurement"],
    log:
        "logs/{sid}/accuracy.log",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    conda:
        "../envs/huefringe.yaml"
    script:
        "../../scripts/accuracy.py"
