"""The rows of a data file a calibration trains and tests on, as ``jaxcal calibrate`` chooses them:
rows the user excludes, the seeded train/test split (the same rows for the same seed on every
machine), marker sessions kept whole on the training side, and dropping training rows (the
``--exclude-outliers`` refit) with every row still named by its line in the file.

Rows are counted two ways, and the names say which: ``*_idx`` are 0-based indices into
:attr:`RowSplit.data` (the file's rows less the excluded ones), ``*_rows`` are 1-based data-row
numbers of the file (what a user sees in a spreadsheet, what ``--exclude-rows`` takes).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["RowSplit", "split_rows"]


@dataclasses.dataclass(frozen=True)
class RowSplit:
    """A data file's rows split for one calibration (:func:`split_rows`).

    Attributes:
        data: the file's rows less the excluded ones (a :class:`~jaxcal.Dataset`).
        kept: ``[n]`` 0-based file rows of ``data``'s rows.
        train_idx, test_idx: 0-based indices into ``data`` of the training and the test rows (the
            test rows empty where a separate test file is used).
        key: the ``jax.random`` key of the method (the seed's second half, as ``jaxcal calibrate``
            passes it to :func:`jaxcal.calibrate`).
        measurement, test_measurement: the measurement model of the training and of the test rows:
            the model given, or a :class:`~jaxcal.SessionMarkers` taken to those rows.
        excluded_rows: the 1-based data rows the user excluded.
        rows_model: a :class:`~jaxcal.SessionMarkers` of every row of :attr:`data` (a model per
            row), from which :attr:`measurement` and :attr:`test_measurement` are taken; ``None``
            for a model that is the same for every row.
    """

    data: object
    kept: np.ndarray
    train_idx: np.ndarray
    test_idx: np.ndarray
    key: object
    measurement: object
    test_measurement: object
    excluded_rows: tuple[int, ...] = ()
    rows_model: object = None

    @property
    def train(self):
        """The training rows (a :class:`~jaxcal.Dataset`)."""
        return self.data.subset(self.train_idx)

    @property
    def test(self):
        """The held-out test rows (a :class:`~jaxcal.Dataset`, possibly empty)."""
        return self.data.subset(self.test_idx)

    def file_rows(self, idx) -> list[int]:
        """The 1-based data rows of the file of ``idx`` (0-based indices into :attr:`data`)."""
        return [int(self.kept[int(i)]) + 1 for i in np.asarray(idx, int).ravel()]

    def train_file_rows(self, positions=None) -> list[int]:
        """The 1-based data rows of the training rows at ``positions`` (0-based positions in
        :attr:`train`, e.g. a fit's outliers ``res.diagnostics.outliers_after``; all by default)."""
        return self.file_rows(self.train_idx if positions is None else self.train_idx[np.asarray(positions, int)])

    def test_file_rows(self, positions=None) -> list[int]:
        """The 1-based data rows of the test rows at ``positions`` (0-based positions in
        :attr:`test`, e.g. :func:`jaxcal.residual_outliers`' rows; all by default)."""
        return self.file_rows(self.test_idx if positions is None else self.test_idx[np.asarray(positions, int)])

    @property
    def train_rows(self) -> list[int]:
        """The 1-based data rows of the training rows, in training order."""
        return self.train_file_rows()

    @property
    def test_rows(self) -> list[int]:
        """The 1-based data rows of the test rows, in test order."""
        return self.test_file_rows()

    def without_train(self, rows) -> RowSplit:
        """This split less the training rows ``rows`` (0-based positions in :attr:`train`, e.g. a
        fit's outliers: ``res.diagnostics.outliers_after``); the test rows are unchanged."""
        keep = np.setdiff1d(np.arange(len(self.train_idx)), np.asarray(rows, int))
        train_idx = self.train_idx[keep]
        measurement = self.measurement if self.rows_model is None else self.rows_model.take(train_idx)
        return dataclasses.replace(self, train_idx=train_idx, measurement=measurement)


def split_rows(data, measurement, *, seed: int = 0, test_fraction: float = 0.2, exclude_rows=(),
               test_file: bool = False) -> RowSplit:
    """The rows of ``data`` (a loaded data file) to train and test ``measurement`` on, as ``jaxcal
    calibrate`` chooses them: ``exclude_rows`` (1-based data rows) left out, then the seeded random
    split of the rest (:func:`jaxcal._datasets._split.seed_split`: the same rows and method key for
    the same seed on every machine), or every row for training where a separate test file is used
    (``test_file``). Marker data of several sessions (a :class:`~jaxcal.SessionMarkers`
    ``measurement`` made from ``data``) need every frame and placement on the training side.

    Args:
        data: a :class:`~jaxcal.Dataset`, all the file's rows.
        measurement: its measurement model (:func:`jaxcal.measurement_for`; a
            :class:`~jaxcal.SessionMarkers` made from ``data`` has a row each).
        seed: the split's seed (``--seed``).
        test_fraction: the share of rows held out for testing, in ``[0, 1)`` (``--test-fraction``).
        exclude_rows: 1-based data rows to leave out (``--exclude-rows``).
        test_file: the test rows come from another file: every kept row trains.

    Returns:
        :class:`RowSplit`.

    Raises:
        ValueError: an excluded row outside ``1..n``; a ``test_fraction`` outside ``[0, 1)``; a
            frame or placement with no training row after the split.
    """
    from .._datasets._split import seed_split

    if not (0.0 <= test_fraction < 1.0):
        raise ValueError(f"the test fraction must be in [0, 1), got {test_fraction}")
    excluded = sorted({int(r) for r in exclude_rows})
    if excluded and (excluded[0] < 1 or excluded[-1] > data.n):
        raise ValueError(f"rows to exclude (--exclude-rows on the command line, exclude_rows in Python): data rows "
                         f"are numbered 1..{data.n}, got {excluded[0]}..{excluded[-1]}")
    kept = np.setdiff1d(np.arange(data.n), np.asarray(excluded, int) - 1)
    data = data.subset(kept)
    key, train_idx, test_idx = seed_split(seed, data.n, test_fraction)
    if test_file:
        train_idx, test_idx = np.arange(data.n), np.arange(0)
    measurement_test, full = measurement, None
    if measurement.row_sessions:  # a model per row of the file: one per row set (train, test)
        full = measurement.take(kept)
        lonely = sorted({lab for i in test_idx for lab in data.labels[i][1:]}
                        - {lab for i in train_idx for lab in data.labels[i][1:]})
        if lonely:
            raise ValueError(f"frame/placement label(s) {lonely} have no training rows after the random split; give "
                             "them more rows, --test-fraction 0, or hold the session out in Python "
                             "(jaxcal.holdout_session)")
        measurement, measurement_test = full.take(train_idx), full.take(test_idx)
    return RowSplit(data, kept, np.asarray(train_idx), np.asarray(test_idx), key, measurement, measurement_test,
                    tuple(excluded), full)
