"""SB3 ``VecNormalize`` statistics for ``--vecnormalize`` (:func:`load_vecnormalize`): an ``.npz``
or ``.json`` with ``mean``, ``var``, ``clip_obs``, ``epsilon``, or SB3's own pickle with
``--trust-pickle``; they become an :class:`~sim2real.deploy.policy.obs_normalizer.ObservationNormalizer`,
``clip((obs - mean) / sqrt(var + epsilon), -clip_obs, clip_obs)``.
"""

from __future__ import annotations

import json
import pickle
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer
from sim2real.deploy.policy.torch_file import CheckpointError


def load_vecnormalize(path: Path, trust_pickle: bool, obs_dim: int) -> ObservationNormalizer | None:
    """SB3 VecNormalize statistics from ``.npz``, ``.json`` or (trusted) pickle.

    Returns:
        The normalizer, or None when the statistics say observations are not normalized
        (``norm_obs = False``).

    Raises:
        ExportError: unreadable file, missing key, wrong size, untrusted pickle.
    """
    if not path.is_file():
        raise ExportError(f"{path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        elif suffix == ".json":
            d = json.loads(path.read_text())
        else:
            if not trust_pickle:
                raise ExportError(
                    f"{path}: VecNormalize statistics saved with pickle (VecNormalize.save); "
                    "unpickling can run arbitrary code. Pass --trust-pickle if you trust the "
                    "file, or save them as .npz (mean, var, clip_obs, epsilon)"
                )
            with open(path, "rb") as f:
                vn = pickle.load(f)  # noqa: S301 - explicitly trusted by the user
            if not getattr(vn, "norm_obs", True):
                return None
            rms = vn.obs_rms
            if isinstance(rms, Mapping):
                raise ExportError(f"{path}: dict observation spaces are not supported")
            d = {"mean": rms.mean, "var": rms.var, "clip_obs": vn.clip_obs, "epsilon": vn.epsilon}
    except ExportError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ExportError(
            f"{path}: cannot read VecNormalize statistics (truncated or corrupt?): "
            f"{_first_line(exc)}"
        ) from None
    if not isinstance(d, Mapping):
        raise ExportError(f"{path}: expected an object with mean, var, clip_obs, epsilon")
    missing = [k for k in ("mean", "var", "clip_obs", "epsilon") if k not in d]
    if missing:
        raise ExportError(f"{path}: VecNormalize statistics lack {missing}")
    try:
        norm = ObservationNormalizer(
            mean=np.asarray(d["mean"], dtype=np.float64).reshape(-1),
            var=np.asarray(d["var"], dtype=np.float64).reshape(-1),
            epsilon=float(np.asarray(d["epsilon"])),
            clip=float(np.asarray(d["clip_obs"])),
        )
        norm.validate(str(path), obs_dim=obs_dim)
    except CheckpointError as exc:
        raise ExportError(str(exc)) from None
    except (TypeError, ValueError) as exc:
        raise ExportError(f"{path}: invalid VecNormalize statistics: {exc}") from None
    return norm
