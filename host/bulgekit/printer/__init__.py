"""The printer link: sending G-code and maps over a serial port (sender).
"""
