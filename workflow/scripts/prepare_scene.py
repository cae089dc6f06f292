"""Adapter: rule prepare_scene -> spc3d.inputs.build.prepare_scene (a capture: captures.importing)."""

from spc3d.jobs import logged

with logged(snakemake.log[0]):
    spec = snakemake.params.spec
    if spec.get("kind") == "capture":
        from spc3d.captures.importing import import_capture_scene

        keys = {"max_features": spec.get("max_features", 4096), "seed": spec.get("seed", 0)}
        import_capture_scene(spec["path"], snakemake.output[0], **keys, overrides=spec.get("overrides"))
    else:
        from spc3d.inputs.build import prepare_scene

        prepare_scene(spec, snakemake.output[0])
