"""Settings checked against each other, in one place: what each value allows alone is the schema's and
the settings dataclasses' (:func:`spc3d.specs.build.check_range`); here are the values that are each
valid but contradict another one, so that a feature would silently never run or a job would fail.

    check_translator(method, cfg, train, where)   architecture (Restormer heads, odd kernels), DDIM steps
    check_reconstructor(model, cfg, where)        schedules inside the run, learning rates that decay,
                                                  the Gaussian cap against the initial points
    check_joint(settings, where)                  a joint row has a term to fit
    check_rows(config, methods, combinations)     the above for every row of the main configuration
    check_point(points, combo, overlay)           the above for one sweep point (its knobs applied)
    unused_blocks(given, rows, nerf_variant)      settings blocks no row reads (a warning each)

Called at parse time by :func:`spc3d.config.check_settings` (the main configuration) and by
:func:`spc3d.sweeps.plan.sweep_points` (every tradeoff / photon_level point). Nothing here imports
Snakemake or torch.
"""

from __future__ import annotations

from spc3d.names import (
    JOINT,
    ConfigError,
    joint_settings,
    parse_combination,
    parse_source,
    row_model,
    stage2_row_settings,
    translator_settings,
)


def check_translator(method: str, cfg, train, where: str) -> None:
    """A translator's network and sampler settings against each other (``cfg``: its model Config,
    ``train``: its TrainSettings; ``where``: ``stage1.{method}`` or a sweep point's name)."""
    if method == "restormer":
        # Level k (1..4) of the encoder works at dim * 2**(k-1) channels split into heads[k-1]
        # heads (the decoder and refinement reuse those widths): spc3d.translate.restormer.
        for level, heads in enumerate(cfg.heads):
            channels = cfg.dim * 2**level
            if heads < 1 or channels % heads:
                fit = [h for h in range(1, channels + 1) if channels % h == 0 and h <= max(heads, 1)][-1]
                raise ConfigError(
                    f"{where}.dim = {cfg.dim}, heads = {list(cfg.heads)}: level {level + 1} has dim x {2**level} = "
                    f"{channels} channels, which {heads} attention heads do not divide; use a dim divisible by "
                    f"{heads} (e.g. {heads * max(1, round(cfg.dim / heads))}) or heads[{level}] = {fit}"
                )
    if method == "diffusion":
        if not 1 <= cfg.sample_steps <= cfg.timesteps:
            raise ConfigError(
                f"{where}.sample_steps = {cfg.sample_steps}: DDIM samples with 1 to timesteps = {cfg.timesteps} "
                f"steps (a subsequence of the {cfg.timesteps} training steps); use e.g. "
                f"{min(10, cfg.timesteps)}"
            )
        if cfg.cleaned_condition and cfg.clean_kernel % 2 == 0:
            raise ConfigError(
                f"{where}.clean_kernel = {cfg.clean_kernel}: a box blur centred on its pixel needs an odd side "
                f"(e.g. {cfg.clean_kernel + 1}); an even one shifts the image by half a pixel"
            )


def check_reconstructor(model: str, cfg, where: str) -> None:
    """A stage-2 model's schedule points inside its run and its learning rates decaying (``cfg``:
    its settings dataclass as the job builds it, ``pose_refine`` included)."""
    if model == "3dgs":
        n = cfg.iterations
        if cfg.densify_until > 0 and cfg.densify_from >= n:
            raise ConfigError(
                f"{where}.densify_from = {cfg.densify_from}: at or after the run's last step (iterations = {n}), "
                f"so densification would never run; start it below {n} (e.g. {max(1, n // 12)}) or set "
                "densify_until: 0 for none"
            )
        if cfg.pose_refine and cfg.pose_from >= n:
            raise ConfigError(
                f"{where}.pose_from = {cfg.pose_from}: at or after the run's last step (iterations = {n}), so "
                f"this row's camera corrections would never move; start them below {n} (e.g. {n // 4})"
            )
        decays = (("lr_means", "lr_means_final"), ("pose_lr", "pose_lr_final"))
    elif model == "nerf-mlp":
        decays = (("lr", "lr_final"),)
    elif model == "nerf-grid":
        late = [it for it, _ in cfg.res_schedule if it >= cfg.n_iters]
        if late:
            shown = [list(entry) for entry in cfg.res_schedule]
            raise ConfigError(
                f"{where}.res_schedule = {shown}: the step(s) {late} are at or after the run's last step "
                f"(n_iters = {cfg.n_iters}), so the grid never reaches those resolutions; keep every "
                f"iteration below {cfg.n_iters} or raise n_iters"
            )
        decays = ()  # lr_decay (the final fraction) is <= 1 by its range
    else:
        decays = ()
    for first, last in decays:
        if getattr(cfg, last) > getattr(cfg, first):
            raise ConfigError(
                f"{where}.{last} = {getattr(cfg, last):g} is above {first} = {getattr(cfg, first):g}: the learning "
                f"rate decays from {first} to {last} over the run, so this would raise it; set {last} <= {first}"
            )


def check_joint(settings: dict, where: str = "stage2.joint") -> None:
    """A joint row fits the SPAD likelihood plus w(t) x a prior term: with the likelihood off and
    both weights 0 it has nothing to fit (``settings``: :func:`spc3d.names.joint_settings`)."""
    from spc3d.specs.reconstructors import config_joint

    cfg = config_joint(settings)
    if not cfg.likelihood and cfg.weight == 0 and cfg.weight_final == 0:
        raise ConfigError(
            f"{where}: likelihood = false and weight = weight_final = 0 turn off both terms of the joint rows, "
            "which then have nothing to fit; keep likelihood: true or give the prior term a weight > 0"
        )


def check_rows(config: dict, methods: list[str], combinations: list[str]) -> None:
    """Every check above for the main configuration: each trained stage-1 method, each row's
    stage-2 settings as its job builds them (:func:`spc3d.names.stage2_row_settings`)."""
    from spc3d.specs.build import build_config
    from spc3d.specs.reconstructors import reconstructor_config
    from spc3d.specs.translators import TrainSettings, model_config

    for method in methods:
        base = parse_source(method).base
        settings, train = translator_settings(config["stage1"], method)
        cfg = model_config(base, settings)
        check_translator(base, cfg, build_config(TrainSettings, train, "stage1.train"), f"stage1.{base}")
    stage2 = config["stage2"]
    for combo in combinations:
        source, model, poses = parse_combination(combo)
        built = reconstructor_config(model, stage2_row_settings(stage2, model, poses))
        check_reconstructor(model, built, f"stage2.{model}")
        if source.startswith(JOINT):
            check_joint(joint_settings(dict(stage2.get("joint") or {}), model), f"stage2.joint ({combo})")


def check_point(points, combo: str, value: str) -> None:
    """Every check above for one sweep point: ``combo`` at overlay ``value`` with the point's knobs
    applied (``points``: :class:`spc3d.sweeps.plan.PointSettings`), as the point's jobs build
    them; an error names the point and its knobs."""
    from spc3d.specs.reconstructors import reconstructor_config
    from spc3d.specs.translators import TrainSettings, model_config

    config = points.config
    source, model, _ = parse_combination(combo)
    where = f"{value.rstrip('/')} ({combo}, knobs {points.setting(value)})"
    try:
        method = parse_source(source).method
        if method is not None:
            base = parse_source(source).base
            settings, train = points.translator(value, base, *translator_settings(config["stage1"], method))
            check_translator(base, model_config(base, settings), TrainSettings(**train), f"{where}: stage1.{base}")
        stage2, knobs = config["stage2"], points.setting(value)
        if model == "3dgs" and "cap" in knobs:
            init = reconstructor_config(model, stage2_row_settings(stage2, model, None)).init_points
            if knobs["cap"] < init:
                key = (
                    "photon_level.budget.cap"
                    if value.startswith("sweeps/photon_level/")
                    else "the cap column of tradeoff.table"
                )
                raise ConfigError(
                    f"{where}: cap = {knobs['cap']} is below stage2.3dgs.init_points = {init}: the point's "
                    f"Gaussians would start above their cap; raise {key} to at least {init} or lower "
                    "stage2.3dgs.init_points"
                )
        settings = points.stage2(value, model, stage2_row_settings(stage2, model, None))
        check_reconstructor(model, reconstructor_config(model, settings), f"{where}: stage2.{model}")
        if source.startswith(JOINT):
            check_joint(joint_settings(dict(stage2.get("joint") or {}), model), f"{where}: stage2.joint")
    except ConfigError:
        raise
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from None


def check_capture_frames(specs: dict[str, dict], combinations: list[str], config: dict) -> None:
    """Every row reads at most the frames per view each capture holds (``specs``: the scene specs,
    a capture's ``frames`` from its sensor.json; a simulated scene's are spc.frames, checked by
    :func:`spc3d.config.check_consistency`)."""
    from spc3d.names import source_frames

    needs = {}
    for combo in combinations:
        source, _, poses = parse_combination(combo)
        for name in (source, poses):
            if name:
                k = source_frames(name, config["stage1"]["frames"], config["stage2"]["frames"])
                if k and k > needs.get("k", (0,))[0]:
                    needs["k"] = (k, combo)
    if not needs:
        return
    k, combo = needs["k"]
    for scene, spec in specs.items():
        if spec["kind"] == "capture" and spec.get("frames") and spec["frames"] < k:
            raise ConfigError(
                f"captures.{scene}: holds {spec['frames']} frames per view (its sensor.json 'frames') but the row "
                f"{combo!r} reads K = {k}; lower that row's K (stage1.frames, stage2.frames or '-k<K>') to at most "
                f"{spec['frames']}, or leave the capture out of scenes.eval"
            )


def unused_blocks(given: dict, rows: list[str], nerf_variant: str) -> list[str]:
    """A warning for each non-empty settings block of ``stage1`` / ``stage2`` in ``given`` (what the
    user's own config files set, not config.yaml's defaults) that no row of ``rows`` (the main
    configuration's and the sweeps') reads: it is silently ignored."""
    from spc3d import specs

    used_methods, used_models, joint = set(), set(), False
    for combo in rows:
        source, model, poses = parse_combination(combo)
        used_models.add(row_model(model, nerf_variant))
        for name in (source, poses or ""):
            if parse_source(name).base in specs.TRANSLATORS:
                used_methods.add(parse_source(name).base)
        joint = joint or source.startswith(JOINT)
    out = []
    for block, registry, used in (
        ("stage1", specs.TRANSLATORS, used_methods),
        ("stage2", specs.RECONSTRUCTORS, used_models | ({"joint"} if joint else set())),
    ):
        for name, settings in (given.get(block) or {}).items():
            if (name in registry or name == "joint") and settings and name not in used:
                what = "model" if block == "stage2" and name != "joint" else "method"
                rows_hint = "no joint-<method> row" if name == "joint" else f"no row uses the {what} {name!r}"
                variant = (
                    f" (the rows' 'nerf' is stage2.nerf_variant = {nerf_variant!r})"
                    if name in ("nerf-mlp", "nerf-grid") and name != nerf_variant
                    else ""
                )
                out.append(
                    f"{block}.{name} is set but {rows_hint} in stage2.combinations, tradeoff or photon_level"
                    f"{variant}: its settings are ignored; add such a row or remove the block"
                )
    return out
