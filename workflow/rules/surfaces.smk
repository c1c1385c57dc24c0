# Meshes and off-screen renders of the selected frames.
# Each rule NAME runs scripts/NAME.py -> huefringe.stages.NAME (section workflow/rules/surfaces.smk).


rule mesh:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        height=R("{sid}", "height", "frame_{frame}.tiff"),
        uncertainty=R("{sid}", "uncertainty", "frame_{frame}.tiff"),
    output:
        ply=R("{sid}", "mesh", "frame_{frame}.ply"),
        stl=R("{sid}", "mesh", "frame_{frame}.stl"),
        stats=R("{sid}", "mesh", "frame_{frame}.stats.json"),
    log:
        "logs/{sid}/mesh_{frame}.log",
    priority: 10  # the metrology report's path (mesh -> render -> metrology) first: see rule metrology
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    params:
        session=session_dir,
        mesh=config["mesh"],
    script:
        "../../scripts/mesh.py"


rule render:
    input:
        camera_json=R("{sid}", "calib", "camera.json"),
        mesh=R("{sid}", "mesh", "frame_{frame}.ply"),
        height=R("{sid}", "height", "frame_{frame}.tiff"),
        phase=R("{sid}", "phase", "frame_{frame}.tiff"),
        uncertainty=R("{sid}", "uncertainty", "frame_{frame}.tiff"),
    output:
        top=report(
            R("{sid}", "renders", "frame_{frame}_top.png"),
            caption="../report/render.rst",
            category="Renders",
        ),
        oblique1=R("{sid}", "renders", "frame_{frame}_oblique1.png"),
        oblique2=R("{sid}", "renders", "frame_{frame}_oblique2.png"),
        height_map=report(
            R("{sid}", "renders", "frame_{frame}_height.png"),
            caption="../report/height_map.rst",
            category="Height maps",
        ),
        phase_map=R("{sid}", "renders", "frame_{frame}_phase.png"),
        uncertainty_map=R("{sid}", "renders", "frame_{frame}_uncertainty.png"),
    log:
        "logs/{sid}/render_{frame}.log",
    priority: 10
    conda:
        "../envs/huefringe.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    params:
        session=session_dir,
        render=config["render"],
    script:
        "../../scripts/render.py"
