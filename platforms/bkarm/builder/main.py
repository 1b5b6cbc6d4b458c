# SCons build script of the bkarm platform: system arm-none-eabi-gcc + newlib,
# bare metal for QEMU's MPS2 boards. The core, options from the environment:
#   custom_cpu     cortex-m3 | cortex-m4          (-mcpu)
#   custom_fpu     none | fpv4-sp-d16             (none: soft float)
#   custom_flash   flash size for the linker, e.g. 256K (the board being mimicked)
#   custom_ram     RAM size, e.g. 48K
# runtime/ holds the vector table, reset code and linker script; output and the
# exit status go through semihosting (newlib's librdimon).
import os

from SCons.Script import AlwaysBuild, Default, DefaultEnvironment

env = DefaultEnvironment()
platform_dir = env.PioPlatform().get_dir()
cpu = env.GetProjectOption("custom_cpu", "cortex-m3")
fpu = env.GetProjectOption("custom_fpu", "none")
flash = env.GetProjectOption("custom_flash", "256K")
ram = env.GetProjectOption("custom_ram", "48K")

env.Replace(
    AR="arm-none-eabi-gcc-ar",
    AS="arm-none-eabi-as",
    CC="arm-none-eabi-gcc",
    CXX="arm-none-eabi-g++",
    # Debian ships no libstdc++ for arm-none-eabi; the core and tests need none
    # (no exceptions, RTTI or STL), so gcc links.
    LINK="arm-none-eabi-gcc",
    OBJCOPY="arm-none-eabi-objcopy",
    RANLIB="arm-none-eabi-gcc-ranlib",
    SIZETOOL="arm-none-eabi-size",
    PROGNAME="firmware",
    PROGSUFFIX=".elf",
    SIZEPRINTCMD="$SIZETOOL -A -d $SOURCES",
)

machine = ["-mcpu=%s" % cpu, "-mthumb"]
if fpu == "none":
    machine.append("-mfloat-abi=soft")
else:
    machine += ["-mfloat-abi=hard", "-mfpu=%s" % fpu]

env.Append(
    ASFLAGS=machine,
    CCFLAGS=machine + ["-ffunction-sections", "-fdata-sections"],
    CXXFLAGS=["-fno-exceptions", "-fno-threadsafe-statics", "-fno-rtti"],
    LINKFLAGS=machine + [
        "-T", os.path.join(platform_dir, "runtime", "bkarm.ld"),
        "-Wl,--defsym=__flash_size=%s" % flash,
        "-Wl,--defsym=__ram_size=%s" % ram,
        "-Wl,--gc-sections",
        "--specs=rdimon.specs",  # semihosting: stdout, exit status
        "-nostartfiles",         # runtime/startup.c is the start-up code
    ],
    LIBS=["m"],
)

env.BuildSources(os.path.join("$BUILD_DIR", "bkarm_runtime"), os.path.join(platform_dir, "runtime"))
program = env.BuildProgram()

AlwaysBuild(env.Alias("size", program, env.VerboseAction("$SIZEPRINTCMD", "Size of $SOURCE")))
Default([program])
