"""The packages' import graph: no cycle between modules, no private name taken from another module.

The graph is read from the source (every ``import`` and ``from ... import``, module-level or inside a
function), so it covers code that a test run might not import. A package's ``__init__`` counts as
a module of its own; importing a submodule imports its packages' ``__init__`` first, which is an
edge too.
"""

import ast
import importlib
import importlib.util
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest

from rigjax.lazy import lazy_exports

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("rigjax", "learnstitch")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(module: str) -> bool:
    return MODULES[module].name == "__init__.py"


def _resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute name of what ``node`` imports from, inside ``module``."""
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if _is_package(module) else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str) -> list[tuple[str, str | None, int]]:
    """``(imported module, imported name or None, line)`` for every import of ``module``."""
    out = []
    for node in ast.walk(ast.parse(MODULES[module].read_text(), str(MODULES[module]))):
        if isinstance(node, ast.Import):
            out += [(alias.name, None, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            source = _resolve(module, node)
            for alias in node.names:
                submodule = f"{source}.{alias.name}"
                if submodule in MODULES:  # ``from . import synthetic``: a module, not a name
                    out.append((submodule, None, node.lineno))
                else:
                    out.append((source, alias.name, node.lineno))
    return out


def _edges() -> dict[str, set[str]]:
    """Module -> the project's modules it imports (and their parent packages)."""
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for module in MODULES:
        for target, _, _ in _imports(module):
            parts = target.split(".")
            for k in range(1, len(parts) + 1):
                prefix = ".".join(parts[:k])
                if prefix in MODULES and prefix != module and not module.startswith(prefix + "."):
                    graph[module].add(prefix)
    return graph


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` (its modules in order, the first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the stack, 2: done
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_walker_sees_the_packages():
    assert {"rigjax", "rigjax.camera.model", "rigjax.optimiser.staged", "learnstitch.network.model"} <= set(MODULES)
    # an edge known from the source: the staged driver imports the compiled solve
    assert "rigjax.optimiser.lm" in _edges()["rigjax.optimiser.staged"]


def test_no_import_cycle():
    cycle = _cycle(_edges())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize("package", PACKAGES)
def test_no_private_name_from_another_module(package):
    found = []
    for module in (m for m in MODULES if m.split(".")[0] == package):
        for source, name, line in _imports(module):
            private_module = any(part.startswith("_") and part != "__init__" for part in source.split("."))
            private_name = name is not None and name.startswith("_") and not name.startswith("__")
            if source.split(".")[0] in PACKAGES and (private_module or private_name):
                found.append(f"{MODULES[module].relative_to(ROOT)}:{line}: {source} import {name}")
    assert not found, "private names imported across modules:\n" + "\n".join(found)


def test_rigjax_does_not_import_learnstitch_or_torch():
    found = [
        f"{MODULES[m].relative_to(ROOT)}:{line}: {source}"
        for m in MODULES
        if m.split(".")[0] == "rigjax"
        for source, _, line in _imports(m)
        if source.split(".")[0] in ("learnstitch", "torch", "kornia")
    ]
    assert not found, found


HEAVY = ("jax", "numpy", "cv2", "optimistix", "jaxopt", "torch", "kornia")


@pytest.mark.parametrize("package", PACKAGES)
def test_the_package_and_its_help_import_no_numerical_library(package):
    # `import rigjax` and `rigjax --help` must not pay for JAX, OpenCV or torch: the package's names
    # are imported on first use, the commands import what they run.
    code = (
        f"import sys, {package}, {package}.cli\n"
        "try:\n"
        f"    {package}.cli.main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(' '.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "usage:" in out
    assert out.splitlines()[-1] == ""


def test_reading_a_project_loads_no_jax():
    # The .pto reader and its lens codes stand apart from the camera model: the video's template
    # mode reads its rig without JAX (its maps come from a cache).
    project = Path(__file__).parent / "rigjax" / "data" / "golden" / "circular_185.pto"
    code = (
        "import sys, rigjax\n"
        f"project = rigjax.load_project({str(project)!r})\n"
        "assert project.images[0].projection == rigjax.Projection.CIRCULAR_FISHEYE and project.to_text()\n"
        "print(' '.join(m for m in ('jax', 'torch') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.splitlines()[-1] == ""


@pytest.mark.parametrize("package", PACKAGES)
def test_every_public_name_resolves_to_its_own_module(package):
    module = importlib.import_module(package)
    assert module.__all__ == sorted(module.__all__) and set(module.__all__) <= set(dir(module))
    for source, names in module._EXPORTS.items():
        for name in names:
            value = getattr(module, name)
            defined_in = value.__name__ if inspect.ismodule(value) else value.__module__
            assert defined_in == importlib.util.resolve_name(source, package), name
    with pytest.raises(AttributeError, match=f"module '{package}' has no attribute 'no_such_name'"):
        module.no_such_name  # noqa: B018


def test_a_name_exported_twice_is_refused():
    with pytest.raises(ValueError, match="exported by two modules"):
        lazy_exports("pkg", {".a": ("x",), ".b": ("x", "y")})


# The public surface, by intent: what the README and the guides use. A name added to or removed from
# a package's __init__ is a decision to make here too.
PUBLIC = {
    "rigjax": """
        CalibrateConfig CalibrateJob CalibrateOutcome Calibration CalibrationError Camera ConfigError
        ControlPoints Equirect Image ImageError LevyConfig MotionConfig OptVariable OptimiseConfig OptimiseJob
        OptimiseOutcome OptimiseResult
        PanoramaLine Project Projection PruneConfig PtoError RenderJob RenderOutcome RigjaxError
        RobustConfig ScheduleError SolverOptions UnsupportedError bundle_adjust calibrate
        calibrate_frames calibrate_job calibrate_matches calibrate_motion config_from_dict cut_image evaluate find_image_circle
        fit_exposure frames_of img_to_pano img_to_ray lens_from_circle load_config load_project
        load_template match_images match_in_seam_band optimise optimise_batch optimise_job optimise_pruned
        pano_to_img pano_to_ray parse_project persist point_errors pool_matches ray_to_img ray_to_pano
        read_image read_video_frames render render_job seam_disagreement setup_worker
        split_side_by_side synthetic template_from_dict transform_points world_from_cam write_image
        with_start ypr_from_world_from_cam
    """,
    "learnstitch": """
        BatchReport ConfigError DepthStitchNet EvalReport FolderDataset GeneratedDataset GivenDepth LossConfig
        ModelConfig NetworkDepth PlaneSweep PreparedProject ProjectStitch RenderConfig Rig Sample
        StitchConfig StitchLoss StitchNet Stitched Stitcher SynthConfig TrainReport TrainingError
        build_model calibrated_depth_stitch calibrated_stitch config_as_dict config_from_dict evaluate
        load_config load_model load_rig make_sample orientation_errors_deg plot_learning_curves
        prepare_project psnr read_fisheyes rig_template rotation_only_stitch ssim stitch stitch_batch
        stitch_fisheyes stitch_project stitch_video synthesise train video_panoramas VideoReport
    """,
}
GUIDES = [ROOT / "README.md", ROOT / "docs" / "rigjax" / "guide.md", ROOT / "docs" / "learnstitch" / "guide.md"]


def _code_in(markdown: str) -> str:
    """The code of a Markdown text: its fenced blocks and its inline code spans."""
    fenced = re.findall(r"```[a-z]*\n(.*?)```", markdown, re.S)
    prose = re.sub(r"```[a-z]*\n.*?```", "", markdown, flags=re.S)
    return "\n".join(fenced + re.findall(r"`([^`\n]+)`", prose))


@pytest.mark.parametrize("package", PACKAGES)
def test_the_public_names_are_the_ones_listed_and_each_is_in_the_guides(package):
    module = importlib.import_module(package)
    assert module.__all__ == sorted(PUBLIC[package].split())
    code = "\n".join(_code_in(path.read_text()) for path in GUIDES)
    undocumented = [name for name in module.__all__ if not re.search(rf"(?<!\w){name}\b", code)]
    assert not undocumented, f"exported by {package} but in no guide's code: {undocumented}"


def test_the_guide_check_reads_code_not_prose():
    text = "A Stitcher in prose.\n\n`load_rig(path)` and\n```python\nx = Stitched()\n```\n"
    code = _code_in(text)
    assert "load_rig" in code and "Stitched" in code and "Stitcher" not in code
