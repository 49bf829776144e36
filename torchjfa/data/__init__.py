"""torchjfa.data"""

from ._differentiate import DEFAULT_CUTOFF_HZ as DEFAULT_CUTOFF_HZ
from ._differentiate import Derivatives as Derivatives
from ._differentiate import differentiate as differentiate
from ._differentiate import savgol_window as savgol_window
