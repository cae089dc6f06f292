"""Adapter: rule simulate_scene -> spc3d.inputs.simulate_scene (a capture: capture_import.import_capture_frames)."""

from spc3d.workflow import logged

with logged(snakemake.log[0]):
    s = snakemake.params.settings
    if "capture" in s:
        from spc3d.capture_import import import_capture_frames

        import_capture_frames(s["capture"], snakemake.input[0], snakemake.output[0], s.get("overrides"))
    else:
        from spc3d.inputs import simulate_scene
        from spc3d.spc import SPCParams

        simulate_scene(
            snakemake.input[0],
            snakemake.output[0],
            SPCParams(**s["physics"]),
            s["flux_scale"],
            s["target_detection"],
            s["seed"],
            capture_factor=s.get("capture_factor", 1),
        )
