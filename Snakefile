# spc3d: binary single-photon-camera images -> colour novel views.
# Thin on purpose: the stages live in workflow/rules/*.smk, the logic in the spc3d library.
import os
import sys
from pathlib import Path

from snakemake.utils import min_version

min_version("8.0")
sys.path.insert(0, f"{workflow.basedir}/workflow")  # a source checkout works without `pip install -e .`
from spc3d.config import read_yaml

# The repository's config.yaml is the default even with --directory elsewhere; --configfile overrides.
# Read once first: a YAML syntax error then names its line (Snakemake's own message does not).
read_yaml(f"{workflow.basedir}/config.yaml")
for _path in workflow.overwrite_configfiles:  # --configfile: a key given twice is named with its line
    read_yaml(_path)


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
        get_final_output(),
    default_target: True
