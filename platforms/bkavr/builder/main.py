# SCons build script of the bkavr platform: system avr-gcc/avr-libc.
# MCU and clock come from the environment's options (custom_mcu, custom_f_cpu)
# because this platform has no board manifests.
from SCons.Script import AlwaysBuild, Default, DefaultEnvironment

env = DefaultEnvironment()
mcu = env.GetProjectOption("custom_mcu", "atmega2560")
f_cpu = env.GetProjectOption("custom_f_cpu", "16000000L")

env.Replace(
    AR="avr-gcc-ar",
    AS="avr-as",
    CC="avr-gcc",
    CXX="avr-g++",
    OBJCOPY="avr-objcopy",
    RANLIB="avr-gcc-ranlib",
    SIZETOOL="avr-size",
    PROGNAME="firmware",
    PROGSUFFIX=".elf",
    SIZEPRINTCMD="$SIZETOOL -A -d $SOURCES",
)

machine = ["-mmcu=%s" % mcu]
env.Append(
    ASFLAGS=machine,
    CCFLAGS=machine + ["-Os", "-ffunction-sections", "-fdata-sections"],
    CXXFLAGS=["-fno-exceptions", "-fno-threadsafe-statics", "-fno-rtti"],
    CPPDEFINES=[("F_CPU", f_cpu)],
    LINKFLAGS=machine + ["-Os", "-Wl,--gc-sections"],
)

program = env.BuildProgram()

AlwaysBuild(env.Alias("size", program, env.VerboseAction("$SIZEPRINTCMD", "Size of $SOURCE")))
Default([program])
