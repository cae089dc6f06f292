"""The library's layering, read from the source.

- Rooms: a module imports only its own room and the rooms below it (:data:`LAYERS`), with no
  import cycle between modules (lazy imports inside functions count; ``if TYPE_CHECKING`` ones,
  which never run, do not). At most :data:`MAX_FLAT` modules sit flat in ``workflow/spc3d/``.
- Stage 1 (spc3d.translate) and stage 2 (spc3d.reconstruct) never import each other; both may use
  the neutral modules (training, checkpoints, io, evaluation.metrics, ...).
- The workflow vocabulary stays torch-free.
"""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from spc3d.provenance import imported_modules, module_name

from conftest import REPO

PACKAGE = REPO / "workflow" / "spc3d"
STAGE1 = ("spc3d.translate",)
STAGE2 = ("spc3d.reconstruct", "spc3d.reconstruct.stage2", "spc3d.reconstruct.sources")


def modules_of(prefix: str) -> list[Path]:
    head = PACKAGE.joinpath(*prefix.split(".")[1:])
    return sorted(head.rglob("*.py")) if head.is_dir() else [head.with_suffix(".py")]


def inside(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def test_import_resolution_on_known_modules():
    """The resolver itself: relative imports of a subpackage module and of an __init__."""
    assert "spc3d.training" in imported_modules(PACKAGE / "translate" / "train.py")
    assert "spc3d.translate.base" in imported_modules(PACKAGE / "translate" / "pix2pix.py")
    assert "spc3d.specs" in imported_modules(PACKAGE / "translate" / "__init__.py")
    assert "spc3d.reconstruct" in imported_modules(PACKAGE / "reconstruct" / "stage2.py")


@pytest.mark.parametrize("side,other", [(STAGE1, STAGE2), (STAGE2, STAGE1)], ids=["stage1", "stage2"])
def test_stage1_and_stage2_do_not_import_each_other(side, other):
    offenders = {}
    for prefix in side:
        for path in modules_of(prefix):
            bad = sorted(m for m in imported_modules(path) if inside(m, other))
            if bad:
                offenders[str(path.relative_to(REPO))] = bad
    assert not offenders, f"imports across the stages (use the neutral modules instead): {offenders}"


def test_workflow_vocabulary_does_not_import_torch():
    """The scene jobs import the simulator and the scoring jobs the scores, with their sRGB and PSNR
    (spc3d.pixels): all must stay torch-free."""
    code = (
        "import sys; sys.path.insert(0, 'workflow'); "
        "import spc3d.specs, spc3d.names, spc3d.config, spc3d.inputs.scenes, spc3d.settings, spc3d.sweeps.plan; "
        "import spc3d.pixels, spc3d.physics.spc, spc3d.inputs.build, spc3d.evaluation.scores; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_planning_the_default_run_imports_neither_torch_nor_scikit_image(tmp_path):
    """Snakemake's own process parses the Snakefile, checks every job's settings (spc3d.specs) and
    plans the jobs: a dry run of the default grid imports neither torch nor scikit-image (each costs
    every invocation about a second); the jobs' own processes import them."""
    code = (
        "import atexit, sys; "
        "atexit.register(lambda: print('IMPORTED', 'torch' in sys.modules, 'skimage' in sys.modules)); "
        f"sys.argv = ['snakemake', '-n', '--quiet', 'rules', '--cores', '1', '--directory', {str(tmp_path)!r}]; "
        "from snakemake.cli import main; main()"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "IMPORTED False False" in out.stdout, out.stdout[-2000:]


# Bottom to top: a module of a layer imports only modules of its own layer or of a lower one.
LAYERS = (
    ("specs", "models", "names", "io", "cameras", "llff", "pixels", "plotting", "runtime", "provenance"),
    ("checkpoints", "training"),
    ("physics",),
    ("poses",),
    ("inputs",),
    ("captures",),
    ("evaluation",),
    ("translate", "reconstruct"),  # side by side, never importing each other (test above)
    ("jobs", "choices", "checks"),  # job glue: logging, scene specs; a fold's choices; checks of settings and targets
    ("settings",),  # what each job runs with, and the results layout
    ("sweeps",),
    ("config",),
)
MAX_FLAT = 15


def room(module: str) -> str:
    return module.split(".")[1] if module.count(".") else ""


def rank(module: str) -> int:
    name = room(module)
    for level, rooms in enumerate(LAYERS):
        if name in rooms:
            return level
    raise AssertionError(f"{module}: room {name!r} is in no layer of tests/test_architecture.py LAYERS")


def package_graph() -> dict[str, set[str]]:
    """module -> the spc3d modules it imports. Names that are attributes, not modules, are dropped, and
    so are a module's own enclosing packages (``from spc3d.reconstruct import nerf`` inside
    ``spc3d.reconstruct.nerf_grid`` imports a sibling; the package is already being imported)."""
    paths = sorted(PACKAGE.rglob("*.py"))
    modules = {module_name(p) for p in paths}
    graph = {}
    for path in paths:
        name = module_name(path)
        enclosing = {".".join(name.split(".")[:k]) for k in range(1, name.count(".") + 1)}
        graph[name] = {m for m in imported_modules(path) if m in modules} - {name} - enclosing
    return graph


def test_every_room_has_a_layer_and_few_modules_are_flat():
    flat = sorted(p.name for p in PACKAGE.glob("*.py") if p.name != "__init__.py")
    assert len(flat) <= MAX_FLAT, f"{len(flat)} modules flat in workflow/spc3d (at most {MAX_FLAT}): {flat}"
    for module in package_graph():
        if module != "spc3d":
            rank(module)


def test_no_import_climbs_to_a_higher_room():
    upward = {
        module: sorted(m for m in deps if room(m) and rank(m) > rank(module))
        for module, deps in package_graph().items()
        if module != "spc3d"
    }
    upward = {k: v for k, v in upward.items() if v}
    assert not upward, f"imports of a higher room (see LAYERS): {upward}"


def test_no_import_cycle():
    graph = package_graph()
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(module: str, path: list[str]) -> list[str] | None:
        state[module] = 1
        for dep in sorted(graph.get(module, ())):
            if state.get(dep) == 1:
                return [*path[path.index(dep) :], dep] if dep in path else [*path, dep]
            if dep not in state and (cycle := visit(dep, [*path, dep])):
                return cycle
        state[module] = 2
        return None

    for module in sorted(graph):
        if module not in state and (cycle := visit(module, [module])):
            raise AssertionError(f"import cycle: {' -> '.join(cycle)}")


def test_the_graph_checks_see_a_climb_and_a_cycle(tmp_path, monkeypatch):
    """The checks themselves, on a graph with one upward import and one cycle."""
    graph = {"spc3d.physics.spc": {"spc3d.evaluation.metrics"}, "spc3d.evaluation.metrics": {"spc3d.physics.spc"}}
    monkeypatch.setattr(sys.modules[__name__], "package_graph", lambda: graph)
    with pytest.raises(AssertionError, match="higher room"):
        test_no_import_climbs_to_a_higher_room()
    with pytest.raises(AssertionError, match="import cycle"):
        test_no_import_cycle()


def reading_path_files(text: str) -> list[Path]:
    """The files of the reading path's table in workflow/rules/README.md, each resolved: a name in
    a row is looked for in the folder of the row's first file, the workflow, spc3d, the scripts or the repo."""
    rows = [line for line in text.splitlines() if re.match(r"\| \d+ \|", line)]
    found, roots = [], [REPO / "workflow", REPO / "workflow" / "spc3d", REPO / "workflow" / "scripts", REPO]
    for row in rows:
        names = re.findall(r"`([\w/.]+\.(?:py|smk|yaml)|[\w/]+/)`", row.split("|")[2])
        first = next(r / names[0] for r in roots if (r / names[0]).exists())
        for name in names:
            folders = [first if first.is_dir() else first.parent, *roots]
            hits = [f / name for f in folders if (f / name).exists()]
            assert hits, f"workflow/rules/README.md reading path: {name!r} (row {row.split('|')[1].strip()}) not found"
            found.append(hits[0].resolve())
    return found


def test_the_reading_paths_files_exist_and_its_count_is_the_one_it_states():
    text = (REPO / "workflow" / "rules" / "README.md").read_text()
    files = {f for f in reading_path_files(text) if f.is_file() and "scripts" not in f.parts}
    stated = re.search(r"the (\d+) files its settings pass through \((\d+)\s+steps\)", text)
    assert stated, "workflow/rules/README.md no longer states its reading path's count"
    assert (len(files), len(re.findall(r"^\| \d+ \|", text, re.M))) == tuple(map(int, stated.groups()))


def test_importing_a_stage2_module_imports_no_trainer_until_the_registry_is_read():
    # spc3d.reconstruct.RECONSTRUCTORS loads every factory's module, so it is built on first use only
    code = (
        "import sys; sys.path.insert(0, 'workflow'); import spc3d.reconstruct.objectives; "
        "loaded = lambda: {m for m in sys.modules if m.endswith(('.splatting', '.nerf_trainer'))}; "
        "before = loaded(); from spc3d.reconstruct import RECONSTRUCTORS; print(sorted(before), sorted(loaded()))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["[]", "['spc3d.reconstruct.nerf_trainer',", "'spc3d.reconstruct.splatting']"]
