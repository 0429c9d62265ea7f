"""Wood measures of branch cylinders (Méndez et al., equations 3–5).

Computed from :class:`~simlidar_mi.geometry.Branches` alone, per tree and in
total, for cylinders of diameter ``d`` and length ``h``:

``V_L = Σ π d² h / 4``
    wood volume (eq. 5), m³.
``A_L = Σ π d h``
    wood (lateral) area (eq. 4), m².
``A_PR = Σ d h``
    projected wood area as the paper computes it (eq. 3): every cylinder seen
    side-on, m².
``A_PR_exact = Σ [d h √(1 − (a·v)²) + (π d²/4) |a·v|]``
    area of each cylinder's orthographic shadow on the plane normal to the
    view direction ``v`` (``a`` = unit axis): side rectangle plus one end
    disc's ellipse. It equals ``d h`` for a cylinder across the view and
    ``π d²/4`` for one seen end-on (eq. 3's second case). Overlaps between
    cylinders are not removed (neither does the paper). Zero-length segments
    contribute nothing.

The default view is ``v = (1, 0, 0)``: the tractor scanner looks along +x at
a row parallel to y.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError
from ..geometry import Branches

#: The scanner looks along +x (row parallel to the y axis).
DEFAULT_VIEW_DIR = (1.0, 0.0, 0.0)


@dataclass(frozen=True)
class WoodMeasures:
    """Measures of one set of cylinders.

    Attributes
    ----------
    n_branches : number of cylinders.
    v_l_m3 : wood volume V_L.
    a_l_m2 : wood area A_L.
    a_pr_m2 : projected area A_PR = Σ d·h (paper, eq. 3).
    a_pr_exact_m2 : exact projected area on the plane normal to the view.
    """

    n_branches: int
    v_l_m3: float
    a_l_m2: float
    a_pr_m2: float
    a_pr_exact_m2: float

    def to_dict(self) -> dict:
        """``{'n_branches', 'V_L_m3', 'A_L_m2', 'A_PR_m2', 'A_PR_exact_m2'}`` (paper names)."""
        return {"n_branches": self.n_branches, "V_L_m3": self.v_l_m3, "A_L_m2": self.a_l_m2,
                "A_PR_m2": self.a_pr_m2, "A_PR_exact_m2": self.a_pr_exact_m2}


@dataclass(frozen=True)
class MeasuresResult:
    """Wood measures in total and per tree.

    Attributes
    ----------
    total : all cylinders.
    per_tree : tree id -> measures, in increasing tree id.
    view_dir : unit view direction used for ``a_pr_exact_m2``.
    """

    total: WoodMeasures
    per_tree: dict[int, WoodMeasures] = field(default_factory=dict)
    view_dir: tuple[float, float, float] = DEFAULT_VIEW_DIR

    def to_dict(self) -> dict:
        """Plain JSON-ready data: the totals at the top level (keys of
        :meth:`WoodMeasures.to_dict`), ``view_dir``, and ``per_tree``, a list of
        the same records with a ``tree_id``, in increasing tree id."""
        return {**self.total.to_dict(), "view_dir": list(self.view_dir),
                "per_tree": [{"tree_id": k, **v.to_dict()} for k, v in self.per_tree.items()]}


def _unit_view(view_dir) -> np.ndarray:
    v = np.asarray(view_dir, np.float64)
    if v.shape != (3,) or not np.isfinite(v).all() or not np.linalg.norm(v) > 0:
        raise ConfigError("must be three finite numbers, not all zero", key="view_dir",
                          value=view_dir)
    return v / np.linalg.norm(v)


def _per_cylinder(branches: Branches, v: np.ndarray) -> np.ndarray:
    """(n, 4) per-cylinder V_L, A_L, A_PR, A_PR_exact."""
    d = np.asarray(branches.diameter, np.float64)
    axis = branches.p1 - branches.p0
    h = np.linalg.norm(axis, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.where(h > 0, np.abs(axis @ v) / h, 0.0)
    cos = np.minimum(cos, 1.0)               # rounding can push |a·v| past 1
    disc = np.pi * d * d / 4.0
    exact = np.where(h > 0, d * h * np.sqrt(1.0 - cos * cos) + disc * cos, 0.0)
    return np.stack([disc * h, np.pi * d * h, d * h, exact], axis=1)


def _summary(values: np.ndarray) -> WoodMeasures:
    s = values.sum(axis=0) if len(values) else np.zeros(4)
    return WoodMeasures(len(values), *(float(x) for x in s))


def wood_measures(branches: Branches, view_dir=DEFAULT_VIEW_DIR) -> MeasuresResult:
    """V_L, A_L, A_PR and exact A_PR of ``branches``, per tree and in total.

    Parameters
    ----------
    branches : cylinders (metres).
    view_dir : direction the scanner looks along; normalised here.

    Returns
    -------
    MeasuresResult

    Examples
    --------
    >>> import numpy as np
    >>> from simlidar_mi.geometry import Branches
    >>> b = Branches(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), np.array([0.05]),
    ...              np.ones(1, np.int32), np.zeros(1, np.int32))
    >>> round(wood_measures(b).total.a_pr_m2, 12)
    0.05
    """
    v = _unit_view(view_dir)
    values = _per_cylinder(branches, v)
    return MeasuresResult(_summary(values), _per_tree(values, np.asarray(branches.tree_id)),
                          tuple(float(x) for x in v))


def _per_tree(values: np.ndarray, ids: np.ndarray) -> dict[int, WoodMeasures]:
    """Summaries of each tree's rows of ``values``, in increasing tree id."""
    if len(ids) > 1 and np.all(ids[1:] >= ids[:-1]):
        # Generated trees come one after another: each tree's rows are a slice (a view, no
        # copy), summed row after row like the masked copy (the same bits).
        starts = np.flatnonzero(np.concatenate([[True], ids[1:] != ids[:-1], [True]]))
        return {int(ids[a]): _summary(values[a:b]) for a, b in zip(starts[:-1], starts[1:])}
    return {int(t): _summary(values[ids == t]) for t in np.unique(ids)}
