"""Benchmarks write their own results page: ``docs/results/NAME.md``.

``with recorded(__file__, __doc__):`` around a benchmark's ``main()`` copies everything it prints to
standard output (its tables and notes) into the page, under the benchmark's description, the
command that produced it, the machine and the date. Progress goes to standard error and stays out
of the page. Nothing is copied by hand: rerunning the benchmark rewrites its page.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import io
import os
import platform
import shlex
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"


class _Tee(io.TextIOBase):
    def __init__(self, *streams) -> None:
        self.streams = streams

    def write(self, text: str) -> int:
        for stream in self.streams:
            stream.write(text)
        return len(text)

    def flush(self) -> None:
        for stream in self.streams:
            stream.flush()


def machine() -> str:
    """The CPU model, the usable cores and the versions that the figures depend on."""
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:
        cores = os.cpu_count()
    accelerators = []
    torch = sys.modules.get("torch")
    if torch is not None and torch.cuda.is_available():
        accelerators.append(torch.cuda.get_device_name())
    jax = sys.modules.get("jax")
    if not accelerators and jax is not None and jax.default_backend() != "cpu":
        accelerators.append(jax.devices()[0].device_kind)
    versions = [f"Python {platform.python_version()}"]
    for name in ("numpy", "jax", "torch"):
        module = sys.modules.get(name)
        if module is not None:
            versions.append(f"{name} {module.__version__}")
    return f"{cpu}, {cores} cores{''.join(f'; {a}' for a in accelerators)}; {', '.join(versions)}"


@contextlib.contextmanager
def recorded(script: str, doc: str | None, page: str | None = None) -> Iterator[None]:
    """Print as usual and, when the body finishes without an error, write the page: the script's
    name, or ``page`` (a run on another device keeps its own page beside the CPU's)."""
    buffer = io.StringIO()
    stdout = sys.stdout
    sys.stdout = _Tee(stdout, buffer)
    try:
        yield
    finally:
        sys.stdout = stdout
    name = Path(script).stem
    target = page or name
    title, _, description = (doc or name).strip().partition("\n")
    command = " ".join(["python", f"benchmarks/{name}.py", *map(shlex.quote, sys.argv[1:])])
    output = buffer.getvalue().strip()
    if not _is_markdown(output):
        output = f"```text\n{output}\n```"
    lines = [
        f"# {title.rstrip('.')}",
        "",
        description.strip("\n").rstrip(),  # keeps an indented usage line a code block
        "",
        f"- command: `{command}`",
        f"- machine: {machine()}",
        f"- date: {datetime.date.today().isoformat()}",
        "",
        "Written by the benchmark itself; rerun the command (or `make bench`) to regenerate it.",
        "",
        output,
    ]
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{target}.md"
    tmp = path.with_suffix(".md.partial")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)
    print(f"wrote {path.relative_to(ROOT)}", file=sys.stderr)


def _is_markdown(text: str) -> bool:
    """Tables print as markdown; anything else is kept verbatim in a code block."""
    return any(line.startswith("|") for line in text.splitlines())


def rig_sample_arguments(doc: str) -> argparse.Namespace:
    """The command line of the benchmarks that run learnstitch's rigs sample by sample:
    ``--samples`` per config, ``--configs`` (``configs/stitch/NAME.yaml``), ``--workers``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--configs", nargs="+", default=["paper_d02", "paper_d04"])
    parser.add_argument("--workers", type=int, default=2)
    return parser.parse_args()
