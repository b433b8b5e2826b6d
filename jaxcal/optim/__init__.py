"""Optimizers as optax gradient transformations: AdaMod and AdaModW (the paper's method).

``scale_by_adamod`` is the composable core (it includes the learning rate, see its notes);
``adamodw`` (decoupled weight decay, eq. 15) and ``adamod`` (no decay) are the aliases.
"""

from ._adamod import ScaleByAdaModState as ScaleByAdaModState
from ._adamod import adamod as adamod
from ._adamod import adamodw as adamodw
from ._adamod import scale_by_adamod as scale_by_adamod

__all__ = ["scale_by_adamod", "ScaleByAdaModState", "adamodw", "adamod"]
