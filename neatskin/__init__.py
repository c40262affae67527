"""neatskin-rig: press campaigns on the NeatSkin impedance-tomography skin.

`neatskin.__version__` is looked up on first use (importlib.metadata costs tens of milliseconds), so
`import neatskin` and `neatskin --help` stay light.
"""


def __getattr__(name: str) -> str:
    if name != "__version__":
        raise AttributeError(f"module 'neatskin' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("neatskin-rig")
    except PackageNotFoundError:  # running from a source tree without installing
        value = "0.0.0+unknown"
    globals()["__version__"] = value
    return value
