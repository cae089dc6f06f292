# Config validation and the small named helpers the rules use (no logic in the rules themselves).
import sys
from pathlib import Path

from snakemake.utils import validate

validate(config, schema="../schemas/config.schema.yaml")

# A source checkout works without `pip install -e .` too.
sys.path.insert(0, str(Path(workflow.basedir) / "workflow"))
from spc3d.augment import split_count
from spc3d.scenes import LAYOUTS
from spc3d.workflow import scene_specs

ENV = "../../envs/spc3d.yaml"
SCENE_SPECS = scene_specs(config, sorted(LAYOUTS), workflow.basedir)
TRAIN_SCENES = list(config["scenes"]["train"])
EVAL_SCENES = list(config["scenes"]["eval"])
ALL_SCENES = TRAIN_SCENES + EVAL_SCENES
COLMAP_INPUTS = list(config["colmap"]["inputs"])


wildcard_constraints:
    scene="|".join(ALL_SCENES) or "(?!)",
    images="rgb|binary|average",


def get_final_output():
    """What `snakemake` builds by default: the data summary and the augmented training pairs."""
    return [
        "results/summary/data_summary.md",
        *expand("results/augment/{scene}", scene=TRAIN_SCENES),
    ]


def get_scene_spec(wildcards):
    return SCENE_SPECS[wildcards.scene]


def get_scene_source(wildcards):
    """The LLFF folder's poses file of a real scene (so edits trigger a rerun); none for built-ins."""
    spec = SCENE_SPECS[wildcards.scene]
    return [Path(spec["path"]) / "poses_bounds.npy"] if spec["kind"] == "llff" else []


def get_spc_settings(wildcards):
    s = config["spc"]
    physics = {k: s[k] for k in ("mode", "q", "tau_d", "exposure_s", "dark_count_rate", "frames")}
    return {"physics": physics, "flux_scale": s["flux_scale"], "target_detection": s["target_detection"],
            "seed": config["seed"]}


def get_augment_count(wildcards):
    return split_count(config["augment"]["count"], len(TRAIN_SCENES), TRAIN_SCENES.index(wildcards.scene))


def get_colmap_images(wildcards):
    """The folder holding the image set a COLMAP run reads."""
    if wildcards.images == "rgb":
        return f"results/scenes/{wildcards.scene}"
    return f"results/spc/{wildcards.scene}"


def get_colmap_subdir(wildcards):
    return {"rgb": "images", "binary": "binary", "average": "average"}[wildcards.images]


def get_summary_roles():
    return ["train"] * len(TRAIN_SCENES) + ["eval"] * len(EVAL_SCENES)
