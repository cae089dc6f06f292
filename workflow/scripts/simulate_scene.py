"""Adapter: rule simulate_scene -> spc3d.inputs.build.simulate_scene
(a capture: spc3d.captures.importing.import_capture_frames)."""

from spc3d.jobs import logged

with logged(snakemake.log[0]):
    s = snakemake.params.settings
    if "capture" in s:
        from spc3d.captures.importing import import_capture_frames

        import_capture_frames(s["capture"], snakemake.input[0], snakemake.output[0], s.get("overrides"))
    else:
        from spc3d.inputs.build import simulate_scene
        from spc3d.physics.spc import SPCParams

        simulate_scene(
            snakemake.input[0],
            snakemake.output[0],
            SPCParams(**s["physics"]),
            s["flux_scale"],
            s["target_detection"],
            s["seed"],
            capture_factor=s.get("capture_factor", 1),
        )
