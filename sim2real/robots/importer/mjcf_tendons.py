"""An MJCF's fixed tendons with limits, kept by the importer.

A linkage the author modelled as independent hinges (a 4-bar ankle's pitch and roll motors)
carries its joint-space limits as ``<tendon><fixed limited="true" range="LOWER UPPER">`` over
those hinges; dropping them lets the plant reach poses the training simulator never could.
:func:`limited_fixed_tendons` names the ones to keep (every other tendon is dropped with the
importer's note) and :func:`drop_tendons_off_hinges` drops those over a joint the import removed
or froze. Pinocchio's MJCF parser ignores tendons; the plant (MuJoCo) enforces their ranges.
"""

from __future__ import annotations

import mujoco


def limited_fixed_tendons(spec: mujoco.MjSpec, model: mujoco.MjModel) -> dict[str, list[str]]:
    """Name -> joints of the ``<tendon><fixed limited="true">``s (a linkage's limits, such as a
    4-bar ankle's, written over its joints); unnamed tendons get a name ``tendon<k>``."""
    taken = {t.name for t in spec.tendons}
    for k, tendon in enumerate(spec.tendons):
        if not tendon.name:
            tendon.name = next(
                f"tendon{j}" for j in range(k + 1, 10**6) if f"tendon{j}" not in taken
            )
            taken.add(tendon.name)
    out = {}
    for i, tendon in enumerate(spec.tendons):  # the compiled model's tendons, in the same order
        adr, num = int(model.tendon_adr[i]), int(model.tendon_num[i])
        types = model.wrap_type[adr : adr + num]
        if model.tendon_limited[i] and num and all(w == mujoco.mjtWrap.mjWRAP_JOINT for w in types):
            ids = model.wrap_objid[adr : adr + num]
            out[tendon.name] = [model.joint(int(j)).name for j in ids]
    return out


def drop_tendons_off_hinges(spec: mujoco.MjSpec, tendons: dict[str, list[str]], notes) -> None:
    """Delete the kept fixed tendons over a joint the import removed or froze (noted)."""
    hinges = {j.name for j in spec.joints}
    dropped = [n for n, joints in tendons.items() if not set(joints) <= hinges]
    for name in dropped:
        spec.delete(spec.tendon(name))
    if dropped:
        notes.append(
            f"{len(dropped)} fixed tendons {dropped[:4]} dropped: over joints the import "
            "removed or froze"
        )
    if len(dropped) < len(tendons):
        kept = [n for n in tendons if n not in dropped]
        notes.append(f"{len(kept)} limited fixed tendons {kept[:4]} kept (their joints' limits)")
