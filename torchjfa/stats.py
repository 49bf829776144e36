"""Sufficient statistics of linear regression.

`Moments` holds N, sum x, sum y, X^T X, X^T y and y^T y in float64. Every estimator in
`torchjfa.estimators` and the projection in `torchjfa.physical` needs nothing else, so a log of
any length is reduced to O(d^2) numbers in one pass: build `Moments` chunk by chunk with
`update`, add the moments of several files with ``+``, and combine processes with
`all_reduce`. Use this module whenever the regression matrix would not fit in memory, or when
the same data is fitted by several estimators.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import torch

from ._validation import as_tensor, check_finite, check_Xy

__all__ = ["CHUNK_SIZE", "Moments", "kfold_moments"]

#: samples per chunk where moments are summed chunk by chunk through the regressor (the
#: default of every ``chunk_size``: memory ``O(chunk * n_dof * n_params)``)
CHUNK_SIZE = 4096

_FIELDS = ("n", "sum_x", "sum_y", "xtx", "xty", "yty")
_BLOCK_ROWS = 2048  # rows per block of `Moments.update` (1.2 MB at d = 77: stays in cache)


class Moments:
    """Weighted sufficient statistics of ``y ~ X``, accumulated in float64.

    Attributes:
        n: total weight (the number of rows when unweighted), 0-d tensor.
        n_rows: number of rows seen (ignores weights), int.
        sum_x: ``sum_i w_i x_i``, shape ``(d,)``.
        sum_y: ``sum_i w_i y_i``, 0-d.
        xtx: ``X^T W X``, shape ``(d, d)``.
        xty: ``X^T W y``, shape ``(d,)``.
        yty: ``y^T W y``, 0-d.

    Example:
        >>> m = Moments.zeros(3)
        >>> for X, y in chunks:            # doctest: +SKIP
        ...     m.update(X, y)
        >>> Ridge(alpha=1.0).fit_moments(m)  # doctest: +SKIP
    """

    def __init__(
        self,
        n: torch.Tensor,
        sum_x: torch.Tensor,
        sum_y: torch.Tensor,
        xtx: torch.Tensor,
        xty: torch.Tensor,
        yty: torch.Tensor,
        n_rows: int = 0,
    ) -> None:
        d = sum_x.shape[-1] if sum_x.ndim == 1 else -1
        shapes = {"n": (), "sum_x": (d,), "sum_y": (), "xtx": (d, d), "xty": (d,), "yty": ()}
        values = {"n": n, "sum_x": sum_x, "sum_y": sum_y, "xtx": xtx, "xty": xty, "yty": yty}
        for key, val in values.items():
            if not isinstance(val, torch.Tensor):
                val = torch.as_tensor(val, dtype=torch.float64, device=sum_x.device)
            if tuple(val.shape) != shapes[key]:
                raise ValueError(
                    f"Moments.{key} must have shape {shapes[key]}, got {tuple(val.shape)}"
                )
            setattr(self, key, val.to(torch.float64))
        self.n_rows = int(n_rows)

    # ------------------------------------------------------------------ construction
    @classmethod
    def zeros(cls, n_features: int, *, device: torch.device | str | None = None) -> Moments:
        """Empty statistics for ``n_features`` inputs, ready for `update`."""
        if int(n_features) < 1:
            raise ValueError(f"n_features must be at least 1, got {n_features}")
        d = int(n_features)
        kw = {"dtype": torch.float64, "device": device}
        return cls(
            torch.zeros((), **kw),
            torch.zeros(d, **kw),
            torch.zeros((), **kw),
            torch.zeros(d, d, **kw),
            torch.zeros(d, **kw),
            torch.zeros((), **kw),
        )

    @classmethod
    def from_data(cls, X, y, weights=None) -> Moments:
        """Statistics of one data set.

        Args:
            X: inputs, shape ``(n, d)``.
            y: outputs, shape ``(n,)``.
            weights: optional non-negative row weights, shape ``(n,)``.
        """
        X, y, weights = check_Xy(X, y, weights, finite=False)
        return cls.zeros(X.shape[1], device=X.device).update(X, y, weights)

    @classmethod
    def from_chunks(cls, chunks: Iterable[tuple], n_features: int | None = None) -> Moments:
        """Accumulate over an iterable of ``(X, y)`` or ``(X, y, weights)`` chunks."""
        m = None if n_features is None else cls.zeros(n_features)
        for chunk in chunks:
            if m is None:
                m = cls.from_data(*chunk)
            else:
                m.update(*chunk)
        if m is None:
            raise ValueError("no chunks given; cannot build Moments of an empty data set")
        return m

    def update(self, X, y, weights=None) -> Moments:
        """Add a chunk of rows in place and return ``self``.

        Args:
            X: shape ``(n, d)``; any floating dtype, accumulated in float64.
            y: shape ``(n,)``.
            weights: optional, shape ``(n,)``.
        """
        # NaN and inf are found from the statistics (a NaN or inf anywhere in a column makes its
        # sum of squares non-finite), which saves a full pass over the chunk; only then is the
        # chunk searched, for the error message.
        X, y, weights = check_Xy(X, y, weights, finite=False)
        if X.shape[1] != self.n_features:
            raise ValueError(f"X has {X.shape[1]} features, these moments have {self.n_features}")
        kw = {"device": self.xtx.device, "dtype": torch.float64}
        y = y.to(**kw)
        # y and a column of ones (or the weights) side by side: X^T [y, 1] in one product
        ones = torch.ones_like(y) if weights is None else weights.to(**kw)
        yw = y * ones if weights is not None else y
        y1 = torch.stack([yw, ones], 1)  # (n, 2)
        d = X.shape[1]
        xtx = torch.zeros(d, d, **kw)
        xt_y1 = torch.zeros(d, 2, **kw)
        # in blocks of rows that stay in cache between the two products (and the float64 copy
        # and the weighting of a block): closer to the cost of the bare X^T X pass than two
        # passes over the whole data
        for a in range(0, X.shape[0], _BLOCK_ROWS):
            Xb = X[a : a + _BLOCK_ROWS].to(**kw)
            Xwb = Xb if weights is None else Xb * ones[a : a + _BLOCK_ROWS, None]
            xtx.addmm_(Xwb.T, Xb)
            xt_y1.addmm_(Xb.T, y1[a : a + _BLOCK_ROWS])
        yty, sum_y = yw @ y, yw.sum()
        if not (
            bool(torch.isfinite(torch.diagonal(xtx)).all())
            and bool(torch.isfinite(xt_y1).all())
            and bool(torch.isfinite(yty))
        ):
            check_finite(X, "X")
            check_finite(y, "y")
            raise ValueError("the statistics of this chunk overflow float64; rescale the data")
        self.n += ones.sum()
        self.sum_x += xt_y1[:, 1]
        self.sum_y += sum_y
        self.xtx += xtx
        self.xty += xt_y1[:, 0]
        self.yty += yty
        self.n_rows += X.shape[0]
        return self

    # ------------------------------------------------------------------ algebra
    def __add__(self, other: Moments) -> Moments:
        if isinstance(other, int) and other == 0:  # lets sum([...]) work
            return self.copy()
        if not isinstance(other, Moments):
            return NotImplemented
        if other.n_features != self.n_features:
            raise ValueError(
                f"cannot add Moments with {self.n_features} and {other.n_features} features"
            )
        return Moments(
            *(getattr(self, k) + getattr(other, k).to(self.xtx.device) for k in _FIELDS),
            n_rows=self.n_rows + other.n_rows,
        )

    __radd__ = __add__

    def __sub__(self, other: Moments) -> Moments:
        """Remove the statistics of ``other`` (a subset of this data), e.g. to leave out a fold."""
        if not isinstance(other, Moments) or other.n_features != self.n_features:
            raise ValueError("can only subtract Moments with the same number of features")
        return Moments(
            *(getattr(self, k) - getattr(other, k).to(self.xtx.device) for k in _FIELDS),
            n_rows=self.n_rows - other.n_rows,
        )

    def copy(self) -> Moments:
        return Moments(*(getattr(self, k).clone() for k in _FIELDS), n_rows=self.n_rows)

    def select(self, index) -> Moments:
        """Statistics of a subset of the inputs (``index``: int indices or a boolean mask)."""
        idx = torch.as_tensor(index, device=self.xtx.device)
        if idx.dtype == torch.bool:
            idx = torch.nonzero(idx).flatten()
        return Moments(
            self.n.clone(),
            self.sum_x[idx],
            self.sum_y.clone(),
            self.xtx[idx][:, idx],
            self.xty[idx],
            self.yty.clone(),
            n_rows=self.n_rows,
        )

    def to(self, device) -> Moments:
        """A copy on ``device`` (the statistics stay float64)."""
        return Moments(*(getattr(self, k).to(device) for k in _FIELDS), n_rows=self.n_rows)

    def all_reduce(self, group=None) -> Moments:
        """Sum the statistics over all processes of ``torch.distributed`` in place.

        Does nothing when no process group is initialised, so the same code runs on one
        process. Every process must call it (it is a collective). Returns ``self``.
        `torchjfa.distributed.all_reduce_moments` reduces several `Moments` in one message.
        """
        import torch.distributed as dist

        if not (dist.is_available() and dist.is_initialized()):
            return self
        flat = self.to_flat()
        dist.all_reduce(flat, op=dist.ReduceOp.SUM, group=group)
        summed = Moments.from_flat(flat, self.n_features)
        for key in (*_FIELDS, "n_rows"):
            setattr(self, key, getattr(summed, key))
        return self

    # ------------------------------------------------------------------ serialisation
    @staticmethod
    def flat_size(n_features: int) -> int:
        """Length of `to_flat`'s vector for ``n_features`` inputs: ``d^2 + 2 d + 4``."""
        d = int(n_features)
        return 1 + d + 1 + d * d + d + 1 + 1

    def to_flat(self) -> torch.Tensor:
        """The statistics as one float64 vector, shape ``(flat_size(d),)``, on their device.

        The layout is ``[n, sum_x (d), sum_y, xtx (d*d, row-major), xty (d), yty, n_rows]``.
        It is linear: the flat vector of a sum of `Moments` is the sum of their flat vectors,
        so an ``all_reduce`` (or any sum) of flat vectors followed by `from_flat` adds
        `Moments`. ``n_rows`` is stored as a float64, exact up to 2^53 rows.
        """
        rows = torch.tensor([float(self.n_rows)], dtype=torch.float64, device=self.xtx.device)
        parts = (self.n.reshape(1), self.sum_x, self.sum_y.reshape(1), self.xtx.reshape(-1))
        return torch.cat([*parts, self.xty, self.yty.reshape(1), rows])

    @classmethod
    def from_flat(cls, flat: torch.Tensor, n_features: int) -> Moments:
        """The `Moments` of a vector laid out by `to_flat` (copied: no storage is shared).

        Args:
            flat: shape ``(flat_size(n_features),)``.
            n_features: d.

        Raises:
            ValueError: if ``flat`` is not 1-D of length ``flat_size(n_features)``.
        """
        d = int(n_features)
        size = cls.flat_size(d)
        if not isinstance(flat, torch.Tensor) or flat.ndim != 1 or flat.shape[0] != size:
            shape = tuple(flat.shape) if isinstance(flat, torch.Tensor) else type(flat).__name__
            raise ValueError(
                f"a flat Moments of {d} features is a 1-D tensor of {size} values, got {shape}"
            )
        n, sx, sy, xtx, xty, yty, rows = flat.to(torch.float64).split((1, d, 1, d * d, d, 1, 1))
        return cls(
            n[0].clone(),
            sx.clone(),
            sy[0].clone(),
            xtx.reshape(d, d).clone(),
            xty.clone(),
            yty[0].clone(),
            n_rows=int(round(float(rows[0]))),
        )

    # ------------------------------------------------------------------ derived quantities
    @property
    def n_features(self) -> int:
        return self.sum_x.shape[0]

    @property
    def mean_x(self) -> torch.Tensor:
        """Weighted mean of the inputs, shape ``(d,)``."""
        self._check_nonempty()
        return self.sum_x / self.n

    @property
    def mean_y(self) -> torch.Tensor:
        """Weighted mean of the output, 0-d."""
        self._check_nonempty()
        return self.sum_y / self.n

    def _check_nonempty(self) -> None:
        if not float(self.n) > 0:
            raise ValueError("these Moments hold no samples (total weight 0); add data first")

    def second_moments(self, center: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(Sxx, Sxy, Syy)``, about the mean when ``center`` else about zero.

        Returns:
            ``Sxx`` of shape ``(d, d)``, ``Sxy`` of shape ``(d,)``, ``Syy`` 0-d; sums, not
            averages (divide by ``n`` for covariances).
        """
        self._check_nonempty()
        if not center:
            return self.xtx, self.xty, self.yty
        mx, my = self.mean_x, self.mean_y
        sxx = self.xtx - self.n * torch.outer(mx, mx)
        sxx = 0.5 * (sxx + sxx.T)
        sxy = self.xty - self.n * mx * my
        syy = self.yty - self.n * my * my
        return sxx, sxy, syy

    def rss(self, coef: torch.Tensor, intercept: float | torch.Tensor = 0.0) -> torch.Tensor:
        """Weighted residual sum of squares ``sum_i w_i (y_i - x_i^T coef - intercept)^2``.

        Computed from the statistics alone, so validation errors of any linear model need no
        pass over the data.
        """
        b = as_tensor(coef, name="coef", dtype=torch.float64, device=self.xtx.device)
        c = torch.as_tensor(intercept, dtype=torch.float64, device=self.xtx.device)
        return (
            self.yty
            - 2 * b @ self.xty
            + b @ self.xtx @ b
            - 2 * c * (self.sum_y - b @ self.sum_x)
            + c * c * self.n
        )

    def __repr__(self) -> str:
        return f"Moments(n_features={self.n_features}, n={float(self.n):g}, n_rows={self.n_rows})"


def kfold_moments(X, y, n_folds: int, weights=None) -> list[Moments]:
    """Moments of ``n_folds`` contiguous folds of one data set (for cross-validation).

    Contiguous, not shuffled: rows of a time series stay with their neighbours, so that
    validation is not flattered by correlated samples on both sides of a split. Fold ``k``
    holds rows ``[k n / K, (k + 1) n / K)``.

    Returns:
        A list of ``n_folds`` `Moments`; their sum is the statistics of the whole data set.
    """
    X, y, weights = check_Xy(X, y, weights, finite=False)  # Moments.update finds NaN and inf
    n = X.shape[0]
    if not 2 <= n_folds <= n:
        raise ValueError(
            f"n_folds must be between 2 and the number of samples ({n}), got {n_folds}"
        )
    bounds = [round(k * n / n_folds) for k in range(n_folds + 1)]
    return [
        Moments.from_data(X[a:b], y[a:b], None if weights is None else weights[a:b])
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]


def as_folds(moments: Moments | Sequence[Moments]) -> tuple[Moments, list[Moments] | None]:
    """Split an estimator's ``fit_moments`` argument into (total, folds or None)."""
    if isinstance(moments, Moments):
        return moments, None
    folds = list(moments)
    if not folds or not all(isinstance(m, Moments) for m in folds):
        raise TypeError("expected a Moments or a non-empty sequence of Moments (CV folds)")
    return sum(folds[1:], folds[0].copy()), folds
