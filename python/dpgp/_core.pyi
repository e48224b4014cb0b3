# Type stubs of the native module dpgp._core (rust/py). Users import dpgp, not this.
import numpy as np
from numpy.typing import NDArray

__version__: str

ParamTuple = tuple[float, float, float, float, float, float, float]

def check_params(p: ParamTuple) -> None: ...
def log_marginal_likelihood(xy: NDArray[np.float64], v: NDArray[np.float64], p: ParamTuple) -> float: ...
def log_predictive(
    train_xy: NDArray[np.float64],
    train_v: NDArray[np.float64],
    test_xy: NDArray[np.float64],
    test_v: NDArray[np.float64],
    p: ParamTuple,
) -> float: ...
def posterior(
    train_xy: NDArray[np.float64], train_v: NDArray[np.float64], query_xy: NDArray[np.float64], p: ParamTuple
) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
