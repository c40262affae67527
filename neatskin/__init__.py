"""neatskin-rig: press campaigns on the NeatSkin impedance-tomography skin."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("neatskin-rig")
except PackageNotFoundError:  # running from a source tree without installing
    __version__ = "0.0.0+unknown"
