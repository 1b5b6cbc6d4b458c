from platformio.public import PlatformBase


class BkarmPlatform(PlatformBase):
    """System arm-none-eabi-gcc; no uploader package, so PlatformIO runs tests
    through test_testing_command (tools/sim/bkqemu) instead of a serial port."""
