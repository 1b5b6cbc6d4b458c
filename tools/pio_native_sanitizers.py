# PlatformIO extra script for env:native: link with the same sanitizers the
# compile step uses (PlatformIO passes build_flags to the compiler only).
Import("env")  # noqa: F821  (SCons injects it)

env.Append(LINKFLAGS=["-fsanitize=address,undefined", "-fno-sanitize-recover=all"])  # noqa: F821
