"""Retargeting: contractions analysed on one face drive another face's basis (Choe & Ko 2001, sec. 5).

Elements are matched by name: exactly first, then by a normalised key (case, separators and side
suffixes: ``mouthSmile_L`` = ``mouth_smile_l`` = ``MouthSmileLeft``). An explicit ``name_map``
{source name: target name} wins over both. Unmatched source elements are dropped (their motion
is lost) and unmatched target elements stay at 0; both lists are reported.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from wface.basis.core import ActuationBasis

__all__ = ["ElementMatch", "RetargetResult", "match_elements", "retarget"]


def _key(name: str) -> str:
    s = re.sub(r"([a-z0-9])([A-Z])", r"\1_\2", name).lower()
    s = s.replace("-", "_").replace(" ", "_")
    m = re.search(r"(?:^|_)(left|right|l|r)$", s)
    side = ""
    if m:
        side = "_" + m.group(1)[0]
        s = s[: m.start()]
    return re.sub(r"[^a-z0-9]", "", s) + side


@dataclass
class ElementMatch:
    """Pairs of matched element indices and what stayed unmatched."""

    pairs: list[tuple[int, int]]
    unmatched_source: list[str]
    unmatched_target: list[str]


def match_elements(
    source_names: Sequence[str], target_names: Sequence[str], *, name_map: Mapping[str, str] | None = None
) -> ElementMatch:
    """Match element names of two bases (see the module docstring for the rules)."""
    src, tgt = list(source_names), list(target_names)
    tgt_index = {n: i for i, n in enumerate(tgt)}
    tgt_key: dict[str, list[int]] = {}
    for i, n in enumerate(tgt):
        tgt_key.setdefault(_key(n), []).append(i)
    pairs, used = [], set()
    name_map = dict(name_map or {})
    for n in name_map.values():
        if n not in tgt_index:
            raise KeyError(f"retarget name_map names target element {n!r}, which the target basis lacks")
    for i, n in enumerate(src):
        j = None
        if n in name_map:
            j = tgt_index[name_map[n]]
        elif n in tgt_index:
            j = tgt_index[n]
        else:
            cands = [c for c in tgt_key.get(_key(n), []) if c not in used]
            if len(cands) == 1:
                j = cands[0]
        if j is not None and j not in used:
            pairs.append((i, j))
            used.add(j)
    matched_src = {i for i, _ in pairs}
    return ElementMatch(
        pairs,
        [n for i, n in enumerate(src) if i not in matched_src],
        [n for j, n in enumerate(tgt) if j not in used],
    )


@dataclass
class RetargetResult:
    """Contractions on the target basis and the animation they make.

    Attributes:
        contractions: (frames, B_target).
        positions_m: (frames, n_target, 3) target vertex positions (None unless asked for).
        match: which elements were paired.
    """

    contractions: np.ndarray
    positions_m: np.ndarray | None
    match: ElementMatch


def retarget(
    contractions: np.ndarray,
    source_names: Sequence[str],
    target: ActuationBasis,
    *,
    name_map: Mapping[str, str] | None = None,
    gains: Mapping[str, float] | None = None,
    synthesize: bool = False,
) -> RetargetResult:
    """Drive ``target`` with contractions analysed on another basis.

    Args:
        contractions: (frames, B_source) or (B_source,).
        source_names: B_source element names of the source basis.
        target: the target basis.
        name_map: explicit {source name: target name} pairs.
        gains: optional per-target-element scale of the contraction (expressive retargeting).
        synthesize: also return the target vertex animation E0' + sum_i x_i e_i'.
    """
    x = np.atleast_2d(np.asarray(contractions, dtype=np.float64))
    if x.shape[1] != len(source_names):
        raise ValueError(f"retarget: {x.shape[1]} contractions for {len(source_names)} source names")
    match = match_elements(source_names, target.names, name_map=name_map)
    if not match.pairs:
        raise ValueError("retarget: no element names in common between source and target bases")
    out = np.zeros((x.shape[0], target.n_elements))
    for i, j in match.pairs:
        out[:, j] = x[:, i]
    for name, g in (gains or {}).items():
        out[:, target.index(name)] *= float(g)
    pos = target.synthesize(out) if synthesize else None
    return RetargetResult(out, pos, match)
