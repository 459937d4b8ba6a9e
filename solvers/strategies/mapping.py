"""Mapping tables: source channels (actor poses, capture channels) -> character shapes.

A mapping is a matrix ``G`` (T, S) plus an offset (T,): ``character = G @ source + offset``.
One-to-one by name is the default (through the alias tables of ``solvers.aliases``); a table
makes it many-to-many with gains (Weta's "expressive translation": one actor pose drives several
character shapes, a character shape is a combination of actor poses).
"""

from dataclasses import dataclass

import numpy as np

from ..character.aliases import match_names, name_key
from ..errors import FacecapError


@dataclass(frozen=True, eq=False)
class Mapping:
    """``target = source @ matrix.T + offset`` for (F, S) source weights.

    source_names : tuple of S names
    target_names : tuple of T names
    matrix : (T, S) gains
    offset : (T,)
    notes : tuple of str, what did not map (for warnings)
    """

    source_names: tuple
    target_names: tuple
    matrix: np.ndarray
    offset: np.ndarray = None
    notes: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "source_names", tuple(self.source_names))
        object.__setattr__(self, "target_names", tuple(self.target_names))
        G = np.asarray(self.matrix, dtype=np.float64)
        S, T = len(self.source_names), len(self.target_names)
        if G.shape != (T, S):
            raise FacecapError(f"mapping: matrix must have shape ({T}, {S}); got {G.shape}")
        if not np.isfinite(G).all():
            raise FacecapError("mapping: gains must be finite")
        off = np.zeros(T) if self.offset is None else np.asarray(self.offset, dtype=np.float64)
        if off.shape != (T,):
            raise FacecapError(f"mapping: offset must have shape ({T},); got {off.shape}")
        object.__setattr__(self, "matrix", G)
        object.__setattr__(self, "offset", off)

    @classmethod
    def by_name(cls, source_names, target_names, *, aliases=True):
        """One-to-one (or one-to-both-sides for FACS units) by name and alias, gain 1."""
        pairs, unmatched_src, unmatched_tgt = match_names(source_names, target_names, aliases=aliases)
        G = np.zeros((len(target_names), len(source_names)))
        for i, j in pairs:
            G[j, i] = 1.0
        notes = []
        if unmatched_src:
            notes.append(f"mapping: {len(unmatched_src)} source channel(s) drive no character shape: {unmatched_src}")
        if unmatched_tgt:
            notes.append(f"mapping: {len(unmatched_tgt)} character shape(s) are not driven and stay at 0: {unmatched_tgt}")
        return cls(source_names, target_names, G, None, tuple(notes))

    @classmethod
    def from_table(cls, table, source_names, target_names, *, keyed_by="source", default="name", aliases=True):
        """Many-to-many mapping from a table.

        Parameters
        ----------
        table : dict
            ``keyed_by="source"``: ``{source: {target: gain, ...} | target | [targets]}`` (one actor
            pose drives several shapes). ``keyed_by="target"``: ``{target: {source: gain, ...} |
            source | [sources]}`` (a character shape is a combination). Names are matched by
            ``name_key`` (case and separators ignored).
        default : "name" or None
            "name": rows/columns the table does not mention map by name/alias as in ``by_name``;
            None: unmentioned channels drive nothing.
        """
        if keyed_by not in ("source", "target"):
            raise FacecapError(f"mapping: keyed_by must be 'source' or 'target'; got {keyed_by!r}")
        if default not in ("name", None):
            raise FacecapError(f"mapping: default must be 'name' or None; got {default!r}")
        src_idx = {name_key(n): i for i, n in enumerate(source_names)}
        tgt_idx = {name_key(n): j for j, n in enumerate(target_names)}
        outer, inner = (src_idx, tgt_idx) if keyed_by == "source" else (tgt_idx, src_idx)
        outer_what, inner_what = ("source", "character shape") if keyed_by == "source" else ("character shape", "source")
        G = np.zeros((len(target_names), len(source_names)))
        mentioned = set()
        for key, entry in table.items():
            if name_key(key) not in outer:
                raise FacecapError(f"mapping: unknown {outer_what} '{key}' in the table")
            a = outer[name_key(key)]
            mentioned.add(a)
            if isinstance(entry, str):
                entry = {entry: 1.0}
            elif isinstance(entry, (list, tuple)):
                entry = {e: 1.0 for e in entry}
            if not isinstance(entry, dict):
                raise FacecapError(f"mapping: entry for '{key}' must be a name, a list of names or {{name: gain}}")
            for name, gain in entry.items():
                if name_key(name) not in inner:
                    raise FacecapError(f"mapping: unknown {inner_what} '{name}' (in the entry for '{key}')")
                if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not np.isfinite(gain):
                    raise FacecapError(f"mapping: gain for '{key}' -> '{name}' must be a finite number; got {gain!r}")
                b = inner[name_key(name)]
                i, j = (a, b) if keyed_by == "source" else (b, a)
                G[j, i] += float(gain)
        notes = []
        if default == "name":
            base = cls.by_name(source_names, target_names, aliases=aliases)
            for j in range(len(target_names)):
                for i in range(len(source_names)):
                    taken = i in mentioned if keyed_by == "source" else j in mentioned
                    if base.matrix[j, i] and not taken:
                        G[j, i] = base.matrix[j, i]
        undriven = [n for j, n in enumerate(target_names) if not G[j].any()]
        unused = [n for i, n in enumerate(source_names) if not G[:, i].any()]
        if unused:
            notes.append(f"mapping: {len(unused)} source channel(s) drive no character shape: {unused}")
        if undriven:
            notes.append(f"mapping: {len(undriven)} character shape(s) are not driven and stay at 0: {undriven}")
        return cls(source_names, target_names, G, None, tuple(notes))

    def apply(self, source_weights):
        """(F, S) -> (F, T)."""
        return np.asarray(source_weights, dtype=np.float64) @ self.matrix.T + self.offset

    def table(self):
        """``{source: {target: gain}}`` of the non-zero gains (for reports and the sidebar list)."""
        out = {}
        for i, s in enumerate(self.source_names):
            row = {self.target_names[j]: float(self.matrix[j, i]) for j in np.flatnonzero(self.matrix[:, i])}
            if row:
                out[s] = row
        return out
