"""cirl-study: reproduce and extend Cooperative Inverse Reinforcement Learning.

Hadfield-Menell, Dragan, Abbeel and Russell, "Cooperative Inverse Reinforcement
Learning", NeurIPS 2016.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cirl-study")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+unknown"
