"""How estimators are named for people: ``display_name("tepinn") == "TE-PINN"``.

Internal ids (``tepinn``, ``vqf-9d``, ``offline-vqf``, ...) stay the keys of every dictionary and of
``metrics.json``; everything a person reads (Markdown tables, figure legends, console summaries,
notes) goes through :func:`display_name`, the one mapping.
"""

from __future__ import annotations

import re

#: ids as people write the methods (without the "-9d" suffix, added as " 9-D").
_BASE = {
    "tepinn": "TE-PINN",
    "lstm": "LSTM",
    "mlp": "MLP",
    "vqf": "VQF",
    "offline-vqf": "offline VQF",
    "riann": "RIANN",
    "fusion": "Fusion",
    "ekf": "EKF",
    "madgwick": "Madgwick",
    "madgwick-original": "Madgwick (original)",
    "complementary": "complementary",
    # TE-PINN variants (``ModelConfig.variant``)
    "tepinn-nophysics": "TE-PINN without physics",
    "tepinn-notransformer": "TE-PINN without transformer",
    "lstm-physics": "LSTM with physics",
    # ablation variants (``tepinn-flight ablate``)
    "full": "full TE-PINN",
    "no-physics": "no physics",
    "no-transformer": "no transformer",
    "no-correction-layer": "no correction layer",
    "no-adaptive-weighting": "no adaptive weighting",
    "no-uncertainty": "no uncertainty",
    "lstm-baseline": "LSTM baseline",
}

#: suffixes that model variants append to their id.
_VARIANT_SUFFIXES = {
    "-nocorrection": "without correction layer",
    "-nouncertainty": "without uncertainty",
    "-noadaptive": "without adaptive weighting",
}


#: suffixes that evaluate's variants of a model (the same network run another way) append to its name
_MODE_SUFFIXES = {"-smooth": "smoothed offline", "-nosmooth": "not smoothed", "-live": "live (the bridge's)"}


#: evaluate --busy-stride N's and the 9-D variants' names (``tepinn-stride6``, ``tepinn-9d``, ``madgwick-9d-beta0.1``)
_STRIDE = re.compile(r"(.+)-stride([0-9]+)")
_NINE_D = re.compile(r"(.+)-9d(?:-beta([0-9.eE+-]+))?")


def reads_as_mode(name: str) -> bool:
    """Whether ``name`` ends as a name evaluate gives a variant of a model (``-live``, ``-nosmooth``, ``-smooth``,
    ``-strideN``, ``-9d``): a model named so would clash with, or read as, another model's variant."""
    return name.endswith(tuple(_MODE_SUFFIXES)) or any(p.fullmatch(name) for p in (_STRIDE, _NINE_D))


def display_name(name: str) -> str:
    """The method as people write it; unknown ids come back unchanged."""
    name = str(name)
    if name in _BASE:
        return _BASE[name]
    for suffix, what in _MODE_SUFFIXES.items():  # evaluate --smooth, --no-smooth, --live (of a model named apart too)
        if name.endswith(suffix) and (shown := display_name(name[: -len(suffix)])) != name[: -len(suffix)]:
            return f"{shown}, {what}"
    m = _STRIDE.fullmatch(name)  # evaluate --busy-stride N
    if m and m.group(1) in _BASE:
        return f"{_BASE[m.group(1)]}, busy stride {m.group(2)}"
    m = _NINE_D.fullmatch(name)
    if m and m.group(1) in _BASE:
        out = f"{_BASE[m.group(1)]} 9-D"
        return out + (f", β = {m.group(2)}" if m.group(2) else "")
    # model variants with ablation suffixes: tepinn-nocorrection-nouncertainty, ...
    rest, extra = name, []
    while True:
        for suf, text in _VARIANT_SUFFIXES.items():
            if rest.endswith(suf) and rest != suf:
                rest, extra = rest[: -len(suf)], [text] + extra
                break
        else:
            break
    if extra and rest in _BASE:
        return f"{_BASE[rest]} " + ", ".join(extra)
    # a learned estimator made unique with its checkpoint's folder: tepinn-run3 -> TE-PINN (run3)
    for base in sorted(_BASE, key=len, reverse=True):
        if name.startswith(base + "-"):
            return f"{display_name(base)} ({name[len(base) + 1:]})"
    return name


__all__ = ["display_name"]
