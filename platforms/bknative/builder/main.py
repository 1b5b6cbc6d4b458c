# SCons build script of the bknative platform: the host's gcc/g++ from PATH.
from SCons.Script import AlwaysBuild, Default, DefaultEnvironment

env = DefaultEnvironment()

env.Replace(
    AR="ar",
    AS="as",
    CC="gcc",
    CXX="g++",
    OBJCOPY="objcopy",
    RANLIB="ranlib",
    SIZETOOL="size",
    PROGNAME="program",
    PROGSUFFIX="",
    SIZEPRINTCMD="$SIZETOOL $SOURCES",
)

program = env.BuildProgram()

AlwaysBuild(env.Alias("exec", program, env.VerboseAction("$SOURCE $PROGRAM_ARGS", "Executing $SOURCE")))
AlwaysBuild(env.Alias("size", program, env.VerboseAction("$SIZEPRINTCMD", "Size of $SOURCE")))
Default([program])
