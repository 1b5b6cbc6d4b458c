from platformio.public import PlatformBase


class BknativePlatform(PlatformBase):
    """Host toolchain from PATH; no packages to install."""
