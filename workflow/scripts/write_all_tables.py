"""Adapter: rules write_all_tables and tables -> spc3d.evaluation.tables.write_all_tables and
spc3d.evaluation.stopping.stopping_table (where each stage-2 row stopped).

write_all_tables gets its metrics as inputs (built first); tables reads whichever of the configured
metrics files exist already, so `snakemake tables` regenerates the tables without training.
"""

import logging
from pathlib import Path

from spc3d.evaluation.stopping import stopping_table
from spc3d.evaluation.tables import write_all_tables
from spc3d.jobs import logged
from spc3d.names import LABELS

with logged(snakemake.log[0]):
    p = snakemake.params
    if snakemake.rule == "tables":
        metrics = [f for f in p.metrics if Path(f).is_file()]
        stage1 = [f for f in p.stage1 if Path(f).is_file()]
        logging.info(
            "%d of %d metrics files and %d of %d stage-1 files exist",
            len(metrics),
            len(p.metrics),
            len(stage1),
            len(p.stage1),
        )
        folder, spc_dirs = p.folder, [d for d in p.spc if Path(d).is_dir()]
    else:
        metrics, stage1 = list(snakemake.input.metrics), list(snakemake.input.stage1)
        folder, spc_dirs = Path(snakemake.output[0]).parent, list(snakemake.input.spc)
    write_all_tables(
        metrics,
        stage1,
        folder,
        p.job.nerf_variant,
        LABELS,
        smallest_effect=p.job.smallest_effect,
        spc_dirs=spc_dirs,
        rivals=p.job.rivals,
    )
    stopping_table(metrics, Path(folder) / "stopping")
