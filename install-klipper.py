#!/usr/bin/env python3
"""Put bulgekit's Klipper module into a Klipper tree, or take it out (docs/klipper.md).

    python3 install-klipper.py ~/klipper              # symlinks (a `git pull` here updates them)
    python3 install-klipper.py ~/klipper --copy       # copies instead
    python3 install-klipper.py ~/klipper --check      # say what would change, change nothing
    python3 install-klipper.py ~/klipper --uninstall  # take it out: the tree as it was
    python3 install-klipper.py ~/kalico --plugins     # Kalico: into klippy/plugins/ instead

It places two entries in klippy/extras/ (or klippy/plugins/):
  bulgekit.py       the module (klipper/extras/bulgekit.py of this checkout)
  bulgekit_host     the host package's directory (host/ of this checkout, holding the Python
                    package `bulgekit`): the module imports the map codec, the reference planner
                    and the Klipper stop model from it, one implementation shared with the
                    `bulgekit` command. With --copy: a copy of its pure-Python modules.
The module needs numpy in Klipper's Python (`~/klippy-env/bin/pip install numpy`, as Klipper's
resonance measurements do). In a git checkout both names go into .git/info/exclude, so the tree
does not read as modified (Moonraker's update manager); --uninstall takes those lines out again.
Running it again changes nothing; switching between link and copy replaces the entries.
"""
import argparse
import filecmp
import os
import shutil
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
MODULE = os.path.join(HERE, "klipper", "extras", "bulgekit.py")
HOST = os.path.join(HERE, "host")
NAMES = ("bulgekit.py", "bulgekit_host")
MARK = "# bulgekit (install-klipper.py)"
SKIP = shutil.ignore_patterns("__pycache__", "*.pyc", "*.so", "*.o", "*.egg-info", "web", "node_modules")


def target_dir(tree, plugins):
    for d in (os.path.join(tree, "klippy"), tree):
        sub = os.path.join(d, "plugins" if plugins else "extras")
        if os.path.isfile(os.path.join(d, "klippy.py")) and os.path.isdir(sub):
            return sub
    raise SystemExit("install-klipper: %s is not a Klipper tree (no klippy/klippy.py with klippy/%s/)"
                     % (tree, "plugins" if plugins else "extras"))


def sources():
    return {"bulgekit.py": MODULE, "bulgekit_host": HOST}


def is_ours(path, src):
    """The entry at path is what this checkout installs (a link to src, or a copy)."""
    if os.path.islink(path):
        return os.path.realpath(path) == os.path.realpath(src)
    if os.path.isfile(path):
        return os.path.isfile(src) and filecmp.cmp(path, src, shallow=False)
    if os.path.isdir(path):
        return os.path.isfile(os.path.join(path, ".bulgekit-copy"))
    return False


def copy_current(path, src):
    """A copy at path equals a fresh copy of src."""
    if os.path.islink(path) or not os.path.exists(path):
        return False
    if os.path.isfile(src):
        return os.path.isfile(path) and filecmp.cmp(path, src, shallow=False)
    want = os.path.join(src, "bulgekit")
    have = os.path.join(path, "bulgekit")
    for root, dirs, files in os.walk(want):
        dirs[:] = [d for d in dirs if not SKIP(root, [d])]
        for f in files:
            if SKIP(root, [f]):
                continue
            rel = os.path.relpath(os.path.join(root, f), want)
            if not os.path.isfile(os.path.join(have, rel)) or not filecmp.cmp(
                    os.path.join(root, f), os.path.join(have, rel), shallow=False):
                return False
    return True


def remove(path):
    if os.path.islink(path) or os.path.isfile(path):
        os.unlink(path)
    elif os.path.isdir(path):
        shutil.rmtree(path)


def place(path, src, copy):
    if not copy:
        os.symlink(src, path)
    elif os.path.isfile(src):
        shutil.copy2(src, path)
    else:
        os.mkdir(path)
        shutil.copytree(os.path.join(src, "bulgekit"), os.path.join(path, "bulgekit"), ignore=SKIP)
        with open(os.path.join(path, ".bulgekit-copy"), "w") as f:
            f.write("copied by install-klipper.py from %s\n" % src)


def git_exclude(tree, dest):
    """(.git/info/exclude path, the lines naming our entries) in a git checkout, else None."""
    root = os.path.abspath(tree)
    while not os.path.isdir(os.path.join(root, ".git")):
        up = os.path.dirname(root)
        if up == root:
            return None
        root = up
    rel = os.path.relpath(dest, root).replace(os.sep, "/")
    return (os.path.join(root, ".git", "info", "exclude"),
            ["/%s/%s" % (rel, n) for n in NAMES])


def exclude_edit(tree, dest, add, dry):
    got = git_exclude(tree, dest)
    if got is None:
        return []
    path, lines = got
    text = open(path).read() if os.path.isfile(path) else ""
    have = text.splitlines()
    block = [MARK] + lines
    present = all(l in have for l in block)
    if add == present:
        return []
    if not dry:
        if add:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            sep = "" if not text or text.endswith("\n") else "\n"
            with open(path, "a") as f:
                f.write(sep + "\n".join(block) + "\n")
        else:
            with open(path, "w") as f:
                f.write("".join(l + "\n" for l in have if l not in block))
    return ["%s %s in %s" % ("add" if add else "remove", ", ".join(lines), path)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("tree", help="the Klipper (or Kalico) checkout, e.g. ~/klipper")
    ap.add_argument("--copy", action="store_true", help="copy the files instead of linking them")
    ap.add_argument("--check", action="store_true", help="only say what would change")
    ap.add_argument("--uninstall", action="store_true", help="take bulgekit out of the tree")
    ap.add_argument("--plugins", action="store_true", help="Kalico: klippy/plugins/, not extras/")
    args = ap.parse_args(argv)
    dest = target_dir(args.tree, args.plugins)
    todo = []
    for name, src in sources().items():
        path = os.path.join(dest, name)
        exists = os.path.lexists(path)
        if exists and not is_ours(path, src):
            raise SystemExit("install-klipper: %s exists and is not bulgekit's: left as it is"
                             % path)
        if args.uninstall:
            if exists:
                todo.append(("remove", path, src))
            continue
        linked = os.path.islink(path)
        if exists and ((not args.copy and linked) or (args.copy and copy_current(path, src))):
            continue
        if exists:
            todo.append(("remove", path, src))
        todo.append(("copy" if args.copy else "link", path, src))
    for verb, path, src in todo:
        what = {"link": "%s -> %s" % (path, src), "copy": "%s to %s" % (src, path)}
        print("%s%s %s" % ("would " if args.check else "", verb, what.get(verb, path)))
        if args.check:
            continue
        if verb == "remove":
            remove(path)
        else:
            place(path, src, verb == "copy")
    for line in exclude_edit(args.tree, dest, not args.uninstall, args.check):
        print(("would " if args.check else "") + line)
    if not todo:
        print("install-klipper: %s: nothing to do (%s)" % (
            dest, "not installed" if args.uninstall else "installed"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
