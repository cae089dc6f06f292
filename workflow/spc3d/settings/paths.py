"""The results layout: the folders and files one job reads, under one root (``results/`` for the
grid, ``results/sweeps/<sweep>/<knob~value/...>/`` for a sweep point). The rules' own output
patterns are the same paths with wildcards (workflow/rules/*.smk); tests/test_settings.py checks
that each path here is one a rule makes (all but a fit's checkpoint, which its job keeps itself)."""

from __future__ import annotations

from dataclasses import dataclass

RESULTS = "results/"


@dataclass(frozen=True)
class Paths:
    """Paths under ``RESULTS + overlay`` (``overlay``: "" or a sweep point's ``sweeps/.../``)."""

    overlay: str = ""

    @property
    def root(self) -> str:
        return f"{RESULTS}{self.overlay}"

    def scene(self, scene: str) -> str:
        return f"{self.root}scenes/{scene}"

    def spc(self, scene: str, rep: str = "") -> str:
        return f"{self.root}spc/{scene}{rep}"

    def augment(self, scene: str, rep: str = "") -> str:
        return f"{self.root}augment/{scene}{rep}"

    def display(self, scene: str, budget: str, rep: str = "") -> str:
        """A scene's metered MLE images of one budget ("k{K}" or "capture")."""
        return f"{self.root}mle/{scene}/{budget}{rep}"

    def calibration(self, fold: str, budget: str, rep: str = "") -> str:
        return f"{self.root}calibration{fold}/display-{budget}{rep}.json"

    def model(self, method: str, sensor: str = "", fold: str = "", rep: str = "") -> str:
        """A trained stage-1 model folder (``sensor``: "" or a capture's "-rggb"; ``fold``: "" or
        "-without-{scene}")."""
        return f"{self.root}models{sensor}{fold}/{method}{rep}"

    def translated(self, scene: str, method: str, rep: str = "") -> str:
        return f"{self.root}translate/{scene}/{method}{rep}"

    def stage1(self, scene: str, source: str, rep: str = "") -> str:
        return f"{self.root}stage1/{scene}/{source}{rep}.json"

    def recon(self, scene: str, combination: str, rep: str = "") -> str:
        return f"{self.root}recon/{scene}/{combination}{rep}"

    def checkpoint(self, scene: str, combination: str, rep: str = "") -> str:
        """Outside the recon folder, so Snakemake's clean-up of a failed job keeps it."""
        return f"{self.root}checkpoints/{scene}/{combination}{rep}/checkpoint.pt"

    def metrics(self, scene: str, combination: str, rep: str = "") -> str:
        return f"{self.root}eval/{scene}/{combination}{rep}/metrics.json"

    # The grid's alone (a sweep point has no COLMAP run, estimated poses or chosen joint weight):
    def colmap(self, scene: str, images: str) -> str:
        return f"{self.root}colmap/{scene}/{images}"

    def poses(self, scene: str, source: str, rep: str = "") -> str:
        return f"{self.root}poses/{scene}/{source}{rep}"

    def choice(self, fold: str, combination: str, rep: str = "") -> str:
        return f"{self.root}choices{fold}/{combination}{rep}.json"

    # The run's reports (the grid's root):
    def table(self, name: str, ext: str) -> str:
        return f"{self.root}tables/{name}.{ext}"

    def figure(self, name: str) -> str:
        return f"{self.root}figures/{name}.png"

    def summary(self, name: str) -> str:
        return f"{self.root}summary/{name}"
