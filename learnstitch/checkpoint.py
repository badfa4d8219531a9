"""Checkpoints: saved atomically, read back without running code, and turned into a model.

A checkpoint is a dict of tensors and plain Python values (``format``, ``model``, ``config`` and,
for ``checkpoint.pt``, the optimiser's state, the step and the RNG), read with
``torch.load(weights_only=True)``. Training writes them (:mod:`learnstitch.training`); evaluation
and inference load the network from them with :func:`load_model`.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

import torch

from rigjax.errors import ConfigError

from .config import StitchConfig, config_as_dict, config_from_dict
from .network import build_model

CHECKPOINT_FORMAT = 1


def config_differences(a: dict, b: dict) -> list[str]:
    """``section.key`` of every value that differs between two config dicts (normalised by
    :func:`config_as_dict`: a key a checkpoint predates counts at its default)."""
    keys = set()
    for section in set(a) | set(b):
        sa, sb = a.get(section), b.get(section)
        if isinstance(sa, dict) and isinstance(sb, dict):
            keys |= {f"{section}.{k}" for k in set(sa) | set(sb) if sa.get(k) != sb.get(k)}
        elif sa != sb:
            keys.add(section)
    return sorted(keys)


def state_digest(state: dict[str, Any]) -> str:
    """SHA-256 of everything in a checkpoint's state but its ``digest``: every tensor's dtype,
    shape and bytes and every other value's ``repr``, in a fixed order. torch does not check a
    file's CRCs, so a damaged tensor would otherwise load without complaint."""
    digest = hashlib.sha256()

    def visit(value: Any, key: str) -> None:
        digest.update(key.encode())
        if isinstance(value, torch.Tensor):
            flat = value.detach().cpu().contiguous().reshape(-1)
            digest.update(f"{flat.dtype}{tuple(value.shape)}".encode())
            digest.update(flat.view(torch.uint8).numpy().tobytes())
        elif isinstance(value, dict):
            for k in sorted(value, key=str):
                visit(value[k], f"{key}/{k}")
        elif isinstance(value, (list, tuple)):
            for k, item in enumerate(value):
                visit(item, f"{key}/{k}")
        else:
            digest.update(repr(value).encode())

    visit({k: v for k, v in state.items() if k != "digest"}, "")
    return digest.hexdigest()


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    """``torch.save`` with the state's digest to a temporary sibling, then an atomic rename: a
    crash leaves the old file."""
    tmp = path.with_name(f".{path.name}.partial")
    torch.save({**state, "digest": state_digest(state)}, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # a truncated or foreign file: several exception types
        raise ConfigError(f"{path}: not a learnstitch checkpoint ({type(error).__name__}: {error})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT or "model" not in state:
        raise ConfigError(f"{path}: not a learnstitch checkpoint (format {CHECKPOINT_FORMAT})")
    # Checkpoints written before digests have none; every one written since is checked.
    if "digest" in state and state["digest"] != state_digest(state):
        raise ConfigError(f"{path}: damaged: its contents do not match the digest written with them")
    return state


# Keys of the data section that trained weights do not depend on: the images' sizes (the networks
# are convolutional and their warps are in normalised units or angles) and the test data's
# jitter and photometry. The rig-aware warp also takes the camera centres at run time.
RUNTIME_DATA_KEYS = frozenset(
    {"fisheye_size", "pano_width", "angle_jitter_deg", "hfov_jitter_deg", "gain_jitter", "vignetting", "noise_std"}
)
RUNTIME_DATA_KEYS_DEPTH = RUNTIME_DATA_KEYS | {"distance"}


def load_model(
    path: str | Path, config: StitchConfig | None = None, device: str | torch.device = "cpu"
) -> tuple[torch.nn.Module, StitchConfig]:
    """The network of a checkpoint (``model.pt`` or ``checkpoint.pt``) in evaluation mode.

    With ``config``, its ``model`` section and the ``data`` keys the weights depend on must be
    those the checkpoint was trained with (otherwise :class:`ConfigError` names the keys that
    differ), and the network is built for ``config``'s rig: a rig-aware model trained at one camera
    distance runs at another.
    """
    state = load_checkpoint(path)
    trained = config_from_dict(state["config"], str(path))
    if config is not None:
        mine, theirs = config_as_dict(config), config_as_dict(trained)
        runtime = RUNTIME_DATA_KEYS_DEPTH if trained.model.warp == "depth" else RUNTIME_DATA_KEYS
        differ = [
            k
            for k in config_differences(mine, theirs)
            if k.startswith("model") or (k.startswith("data") and k.partition(".")[2] not in runtime)
        ]
        if differ:
            detail = ", ".join(
                f"{k}: {_get(theirs, k)!r} in the checkpoint, {_get(mine, k)!r} in {config.name or 'the config'}"
                for k in differ
            )
            raise ConfigError(f"{path} was trained with another config ({trained.name!r}): {detail}")
    model = build_model(trained.model, trained.data if config is None else config.data)
    model.load_state_dict(state["model"])
    return model.to(device).eval(), trained


def _get(config: dict, key: str):
    section, _, name = key.partition(".")
    return config.get(section, {}).get(name) if name else config.get(section)
