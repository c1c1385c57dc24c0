# huefringe: one-shot trapezoidal HSI fringe projection, from capture sessions to metrology.
# Usage: snakemake --cores 2 [--configfile my.yaml]. Rules live in workflow/rules/.
import sys
from pathlib import Path

from snakemake.utils import min_version, validate

min_version("9.0")

from huefringe.plan import config_problems
from huefringe.settings import DEFAULTS_PATH


# the library's defaults, then this repository's sessions (and any --configfile) over them
configfile: str(DEFAULTS_PATH)
configfile: "config.yaml"


if _problems := config_problems(
    config, f"{workflow.basedir}/workflow/schemas/config.schema.yaml"
):
    sys.exit(
        "\nhuefringe: the configuration ({}) is not valid:\n  {}\nSee workflow/schemas/config.schema.yaml.\n".format(
            ", ".join(str(f) for f in workflow.configfiles if Path(f) != DEFAULTS_PATH),
            "\n  ".join(_problems),
        )
    )
validate(config, "workflow/schemas/config.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/bench.smk"
include: "workflow/rules/calibration.smk"
include: "workflow/rules/measurement.smk"
include: "workflow/rules/surfaces.smk"
include: "workflow/rules/metrology.smk"
include: "workflow/rules/rig.smk"
include: "workflow/rules/archive.smk"


rule all:
    default_target: True
    input:
        all_targets(),
