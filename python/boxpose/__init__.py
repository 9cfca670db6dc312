"""boxpose from Python: the geometry core on numpy arrays (the compiled `boxpose.boxpose`, built
from rust/python by maturin; typed by `boxpose.pyi` beside it) and `read_dataset`, a dataset's
tables checked against the contract (from `boxpose_io`, pyarrow only)."""

from boxpose.boxpose import *  # noqa: F403  (every function of the compiled module)
from boxpose.boxpose import __all__ as _compiled
from boxpose_io import DatasetError, read_dataset

__all__ = [*_compiled, "DatasetError", "read_dataset"]
