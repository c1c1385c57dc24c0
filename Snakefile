# huefringe: one-shot trapezoidal HSI fringe projection, from capture sessions to metrology.
# Usage: snakemake --cores 2 [--configfile my.yaml]. Rules live in workflow/rules/.
import sys

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config.yaml"


from huefringe.plan import config_problems

if _problems := config_problems(
    config, f"{workflow.basedir}/workflow/schemas/config.schema.yaml"
):
    sys.exit(
        "\nhuefringe: the configuration ({}) is not valid:\n  {}\nSee workflow/schemas/config.schema.yaml.\n".format(
            ", ".join(map(str, workflow.configfiles)), "\n  ".join(_problems)
        )
    )
validate(config, "workflow/schemas/config.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/bench.smk"
include: "workflow/rules/calibration.smk"
include: "workflow/rules/measurement.smk"
include: "workflow/rules/surfaces.smk"
include: "workflow/rules/metrology.smk"
include: "workflow/rules/archive.smk"


rule all:
    default_target: True
    input:
        all_targets(),
