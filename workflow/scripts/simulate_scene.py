"""Adapter: rule simulate_scene -> spc3d.inputs.simulate_scene."""

from spc3d.inputs import simulate_scene
from spc3d.spc import SPCParams
from spc3d.workflow import logged

with logged(snakemake.log[0]):
    s = snakemake.params.settings
    simulate_scene(
        snakemake.input[0],
        snakemake.output[0],
        SPCParams(**s["physics"]),
        s["flux_scale"],
        s["target_detection"],
        s["seed"],
    )
