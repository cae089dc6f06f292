# spc3d: binary single-photon-camera images -> colour novel views.
# Thin on purpose: the stages live in workflow/rules/*.smk, the logic in the spc3d library.
import os
import sys
from pathlib import Path

from snakemake.utils import min_version, update_config

min_version("8.0")
sys.path.insert(0, f"{workflow.basedir}/workflow")  # a source checkout works without `pip install -e .`
from spc3d.config import read_yaml
from spc3d.checks.crosscheck import unused_blocks
from spc3d.checks.targets import check_targets, command_line_targets, is_fresh_folder, remove_if_unused

# A refused run leaves no --directory behind: Snakemake makes the folder before it reads this file,
# so one that is new and still holds no file when the process ends goes (spc3d.checks.targets).
if workflow.overwrite_workdir and is_fresh_folder(os.getcwd()):
    import atexit

    atexit.register(remove_if_unused, os.getcwd())

# The repository's config.yaml is the default even with --directory elsewhere; --configfile overrides.
# Read once first: a YAML syntax error then names its line (Snakemake's own message does not).
read_yaml(f"{workflow.basedir}/config.yaml")
# --configfile: a key given twice, an octal or base-60 number is named with its line
USER_CONFIG = [read_yaml(_path) for _path in workflow.overwrite_configfiles]


configfile: f"{workflow.basedir}/config.yaml"


# `snakemake --cores 2 --cache`: trained translators are stored in and reused from this folder by
# every workflow directory (the rules marked `cache: True`; docs/stage1.md#trained-once-reused).
# Snakemake refuses a cache folder that does not exist: the default one is made here.
DEFAULT_CACHE = Path.home() / ".cache" / "spc3d" / "outputs"
if os.environ.setdefault("SNAKEMAKE_OUTPUT_CACHE", str(DEFAULT_CACHE)) == str(DEFAULT_CACHE):
    DEFAULT_CACHE.mkdir(parents=True, exist_ok=True)


# `snakemake --report results/report.html`: one self-contained page (captions in workflow/report/).
report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/inputs.smk"
include: "workflow/rules/colmap.smk"
include: "workflow/rules/summary.smk"
include: "workflow/rules/stage1.smk"
include: "workflow/rules/stage2.smk"
include: "workflow/rules/tradeoff.smk"


rule all:
    input:
        TARGETS.final(),
    default_target: True


# A target no rule makes is answered in the project's words: which scene, row or named target is
# unknown, the configured ones and the nearest (Snakemake's "No rule to produce" lists none).
check_targets(
    command_line_targets(),
    lambda target: any(r.is_producer(target) for r in workflow.rules),
    ["all", *(r.name for r in workflow.rules if not r.output and r.name != "all")],
    list(dict.fromkeys(ALL_SCENES + list(SWEEP_SPECS))),
    COMBINATIONS + TRADEOFF_COMBOS + PHOTON_COMBOS,
    [r.name for r in workflow.rules],
)

# A settings block the user's own files set for a model no row uses is ignored: say so (spc3d.checks.crosscheck;
# the presets set blocks for several targets on purpose).
_given, _presets = {}, Path(workflow.basedir, "workflow", "presets").resolve()
for _path, _part in zip(workflow.overwrite_configfiles, USER_CONFIG):
    if Path(_path).resolve().parent != _presets:
        update_config(_given, _part)
update_config(_given, dict(workflow.config_settings.config or {}))
for _warning in unused_blocks(_given, COMBINATIONS + TRADEOFF_COMBOS + PHOTON_COMBOS, config["stage2"]["nerf_variant"]):
    print(f"spc3d warning: {_warning}", file=sys.stderr)
