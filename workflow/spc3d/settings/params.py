"""What a job runs with, as one typed object per rule: built by the job's settings object
(:class:`spc3d.settings.Grid`, or a sweep point's) and handed to its script whole as ``params.job``.

Each is a ``NamedTuple``, not a dataclass, on purpose: Snakemake reruns a job whose params changed
(``--rerun-triggers params``) by comparing their ``repr``, but only for builtin types; any other
object is dropped from the comparison without a word, so a changed setting inside a dataclass
would rerun nothing. A ``NamedTuple`` is a tuple: its fields (names and values) are compared.
``tests/test_settings.py`` checks that every rule's object is one Snakemake compares.
"""

from __future__ import annotations

from typing import NamedTuple


class ColmapParams(NamedTuple):
    """COLMAP on one image set of a scene (rule colmap_poses)."""

    subdir: str  # the image folder inside the input: "images", "binary" or "average"
    max_features: int
    seed: int


class PosesParams(NamedTuple):
    """COLMAP on a source's images of the training views (rule estimate_poses)."""

    subdir: str  # the image folder inside the source's
    frames: int | None  # binary frames per view the images come from (None: the ground truth)
    max_features: int
    seed: int


class DisplayParams(NamedTuple):
    """A metered MLE display (rules calibrate_display and write_display)."""

    frames: int  # its first K frames
    capture: bool  # the capture-resolution frame (then K = 1)


class AugmentParams(NamedTuple):
    """The augmented training pairs of one training scene (rule augment_scene)."""

    n_pairs: int
    settings: dict  # the augment block: count and ranges
    seed: int


class TranslatorParams(NamedTuple):
    """One stage-1 training (rule train_translator)."""

    method: str  # the method trained ("pix2pixhd" for "pix2pixhd-pub", whose settings say prior_sigma 0)
    settings: dict  # the model's overrides
    train: dict  # its training settings
    frames: int  # binary frames per input
    data: str  # "fixed" augmented pairs or "online" samples
    augment: dict  # the ranges online samples draw from
    sensor: str | None  # a capture's sensor ("cfa", "white") the inputs are recorded by; None: the simulator's
    validation: dict
    seed: int
    code: str  # the library code the weights depend on (spc3d.provenance): a change retrains


class TranslateParams(NamedTuple):
    """Every view of a scene through a trained stage-1 method (rule translate_scene)."""

    frames: int
    ensemble: int


class ScoreParams(NamedTuple):
    """A source's images scored before 3D (rule score_images)."""

    subdir: str
    frames: int | None
    capture_factor: int
    seed: int


class ReconstructParams(NamedTuple):
    """One stage-2 fit (rule reconstruct)."""

    settings: dict  # the model's settings for the row
    seed: int
    frames: int | None  # binary frames per view the source consumes (None: the oracle)
    init: str | None  # where a 3DGS fit's points start ("colmap", "random"; None: a sweep point's random)
    observe: bool  # stage2.observe_plateau: train on past a stop, to measure it
    checkpoint: str  # where the fit keeps its checkpoint
    policy: dict  # the checkpoints block
    joint: dict | None  # a joint row's prior schedule; None for every other row
    code: str  # the library code the fit runs (spc3d.provenance): a change refits


class ChoiceParams(NamedTuple):
    """A fold's choice of a joint row's prior weight (rule choose_joint_weight)."""

    settings: dict
    joint: dict
    candidates: list[float]
    seed: int
    frames: int | None
    display: tuple[int, bool, str]  # (K, capture, budget) of the display the joint row reads


class TablesParams(NamedTuple):
    """The paper-layout tables and the findings (rules write_all_tables and tables)."""

    nerf_variant: str
    smallest_effect: float
    rivals: dict[str, list[str]]  # the rows each "every ..." claim compares with


class SweepReportParams(NamedTuple):
    """A sweep's table and figure (rules tradeoff_report and photon_level_report)."""

    points: list[dict]  # each point's files and its jobs' benchmark files
    combos: list[str]
    clock: str | None = None  # tradeoff.clock: the time a point is charged ("wall", "cpu"); None: photon level


# Every params object, for the check that Snakemake compares each (tests/test_settings.py).
PARAMS = (
    ColmapParams,
    PosesParams,
    DisplayParams,
    AugmentParams,
    TranslatorParams,
    TranslateParams,
    ScoreParams,
    ReconstructParams,
    ChoiceParams,
    TablesParams,
    SweepReportParams,
)
