"""cirl-study: reproduce and extend Cooperative Inverse Reinforcement Learning.

Hadfield-Menell, Dragan, Abbeel and Russell, "Cooperative Inverse Reinforcement
Learning", NeurIPS 2016.
"""

__version__ = "0.1.0"
"""The package's version, and its one source: ``pyproject.toml`` reads it from here (reading
it back from the installed metadata instead cost every command 40 ms of start-up)."""
