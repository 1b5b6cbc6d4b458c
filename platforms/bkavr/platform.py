from platformio.public import PlatformBase


class BkavrPlatform(PlatformBase):
    """System avr-gcc; no uploader package, so PlatformIO runs tests through
    test_testing_command (the simulator) instead of a serial port."""
