"""Learning curves of training runs: ``learnstitch curves RUN [RUN ...] -o curves.png``.

A run folder (:mod:`learnstitch.training`) holds ``metrics.jsonl`` (the training loss every
``log_every`` steps) and, with ``train.validate_every``, ``validation.jsonl``: per validation,
the mean PSNR over the seen pixels of the validation samples, rendered as configured and
photometrically clean, with the network's colour correction on and off, beside the true-rotation
stitch's on the same samples. Training redraws ``learning_curves.png`` in the run folder at each
validation; this command draws several runs on one figure.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from rigjax.errors import ConfigError


def read_jsonl(path: Path) -> list[dict]:
    """The records of a JSON-lines file; a line cut short by a crash is skipped."""
    if not path.is_file():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def plot_learning_curves(runs: dict[str, Path], path: str | Path) -> Path:
    """Draw the runs (label -> run folder) to ``path`` (PNG), written atomically: training loss
    against steps, and validation PSNR over seen pixels (as configured and clean, gain on and
    off, the true-rotation stitch dotted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax_loss, *ax_sets = axes
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    found = reference = False
    for k, (label, run) in enumerate(runs.items()):
        run = Path(run)
        colour = colours[k % len(colours)]
        losses = read_jsonl(run / "metrics.jsonl")
        validation = read_jsonl(run / "validation.jsonl")
        found |= bool(losses or validation)
        if losses:
            ax_loss.plot([r["step"] for r in losses], [r["loss"] for r in losses], color=colour, lw=0.8, label=label)
        steps = [r["step"] for r in validation]
        for ax, data in zip(ax_sets, ("configured", "clean")):
            if not validation:
                continue
            ax.plot(steps, [r[data]["network"] for r in validation], "-o", ms=3, color=colour, label=f"{label}")
            if "network_gain_off" in validation[0][data]:
                gain_off = [r[data]["network_gain_off"] for r in validation]
                ax.plot(steps, gain_off, "--", color=colour, label=f"{label}, colour correction off")
            if not reference:  # the same validation samples in every run: drawn once
                truth = [r[data]["rotation_only"] for r in validation]
                ax.plot(steps, truth, ":", color="black", label="true-rotation stitch")
        reference |= bool(validation)
    if not found:
        plt.close(fig)
        raise ConfigError(f"no metrics.jsonl or validation.jsonl in {', '.join(str(r) for r in runs.values())}")
    ax_loss.set(title="training loss", xlabel="step", yscale="log")
    for ax, data in zip(ax_sets, ("as configured", "photometrically clean")):
        ax.set(title=f"validation PSNR, seen pixels ({data})", xlabel="step", ylabel="dB")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    tmp = path.with_name(f".{path.name}.partial.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)
    return path
