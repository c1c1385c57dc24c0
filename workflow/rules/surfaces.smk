# Meshes and off-screen renders of the selected frames.


rule mesh:
    input:
        height=R("{sid}", "height", "frame_{frame}.tiff"),
    output:
        ply=R("{sid}", "mesh", "frame_{frame}.ply"),
        stl=R("{sid}", "mesh", "frame_{frame}.stl"),
        stats=R("{sid}", "mesh", "frame_{frame}.stats.json"),
    params:
        session=session_dir,
        mesh=config["mesh"],
    log:
        "logs/{sid}/mesh_{frame}.log",
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    conda:
        "../envs/huefringe.yaml"
    script:
        "../../scripts/mesh.py"


rule render:
    input:
        mesh=R("{sid}", "mesh", "frame_{frame}.ply"),
        height=R("{sid}", "height", "frame_{frame}.tiff"),
        phase=R("{sid}", "phase", "frame_{frame}.tiff"),
        uncertainty=R("{sid}", "uncertainty", "frame_{frame}.tiff"),
    output:
        top=report(R("{sid}", "renders", "frame_{frame}_top.png"), caption="../report/render.rst", category="Renders"),
        oblique1=R("{sid}", "renders", "frame_{frame}_oblique1.png"),
        oblique2=R("{sid}", "renders", "frame_{frame}_oblique2.png"),
        height_map=report(
            R("{sid}", "renders", "frame_{frame}_height.png"), caption="../report/height_map.rst", category="Height maps"
        ),
        phase_map=R("{sid}", "renders", "frame_{frame}_phase.png"),
        uncertainty_map=R("{sid}", "renders", "frame_{frame}_uncertainty.png"),
    params:
        session=session_dir,
        render=config["render"],
    log:
        "logs/{sid}/render_{frame}.log",
    threads: 1
    resources:
        mem_mb=3000,
        runtime=10,
    conda:
        "../envs/huefringe.yaml"
    script:
        "../../scripts/render.py"
