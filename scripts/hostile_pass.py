#!/usr/bin/env python3
"""A hostile pass over cgenreg's output files, run-file readers, stdout and the paths that go
into Slurm scripts, through the real binary. Prints one line per failed case and the counts
per class; exits 1 when a case fails.

    python3 scripts/hostile_pass.py target/debug/cgenreg

A case fails when the binary panics, hangs (10 s), exits 0 where it must refuse, changes a
file it must leave alone (a FIFO, a link, a foreign file), leaves a `.tmp` file, runs a command
injected through a path, or gives an error that does not name the file.
"""

import json
import os
import stat
import subprocess
import sys
import tempfile

BIN = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else "target/debug/cgenreg")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEMO = os.path.join(ROOT, "assets/demo/demo.toml")
ENV = {k: v for k, v in os.environ.items() if not k.startswith("CGENREG_")}

counts = {}
failures = []


def record(cls, name, ok, why=""):
    c = counts.setdefault(cls, [0, 0])
    c[0] += 1
    if ok:
        c[1] += 1
    else:
        failures.append(f"{cls}: {name}: {why}")


def run(args, timeout=10, stdout=subprocess.PIPE, env=None, cwd=None):
    try:
        p = subprocess.run(
            [BIN] + args,
            stdout=stdout,
            stderr=subprocess.PIPE,
            timeout=timeout,
            env=env or ENV,
            cwd=cwd,
        )
        return p.returncode, (p.stdout or b"").decode(errors="replace"), p.stderr.decode(
            errors="replace"
        )
    except subprocess.TimeoutExpired:
        return None, "", "TIMEOUT"


def kind(p):
    try:
        m = os.lstat(p)
    except FileNotFoundError:
        return "missing"
    if stat.S_ISLNK(m.st_mode):
        return "link->" + os.readlink(p)
    if stat.S_ISFIFO(m.st_mode):
        return "fifo"
    if stat.S_ISCHR(m.st_mode):
        return "chardev"
    if stat.S_ISDIR(m.st_mode):
        return "dir"
    with open(p, "rb") as f:
        return "file:" + f.read().hex()


def run_file(index, count, shard_count, n, ids):
    return {
        "manifest": "m.toml",
        "params": {},
        "run": {
            "identity": {
                "command": "generate",
                "manifest": "m.toml",
                "manifest_blake3": "00",
                "split": None,
                "limit": None,
                "params": {},
                "shard_count": shard_count,
                "code_version": "cgenreg 0",
                "binary_blake3": "00",
                "selected": [f"t/p{i}" for i in range(n)],
            },
            "shard": {"index": index, "count": count},
            "complete": False,
            "in_flight": None,
            "host": "h",
            "updated_unix": 0,
        },
        "records": [
            {"id": i, "status": "done", "time_s": 0.5, "stages": [], "result": {}} for i in ids
        ],
    }


def three_shards(d):
    os.makedirs(os.path.join(d, "shards"), exist_ok=True)
    out = []
    for i in range(3):
        p = os.path.join(d, "shards", f"shard-{i}.json")
        with open(p, "w") as f:
            json.dump(run_file(i, 3, 3, 6, [f"t/p{i}", f"t/p{i + 3}"]), f)
        out.append(p)
    return out


def tmp_left(d):
    return [
        os.path.join(r, n)
        for r, ds, fs in os.walk(d)
        for n in ds + fs
        if ".tmp" in n
    ]


# ------------------------------------------------------------------ A. paths into scripts
def pass_scripts(t):
    names = [f"x{chr(c)}y" for c in list(range(1, 32)) + [127]]
    names += [
        "a'b", 'a"b', "$(touch MARK)", "`touch MARK`", "a;touch MARK", "a&touch MARK",
        "a|touch MARK", "a>MARK", "a<b", "a*?[b]", "a\\b", "a!b", "#a", "a%b", "a b",
        "ü€", "'$(touch MARK)'", "a\u2028b", "a\u0085b",
    ]
    for i, name in enumerate(names):
        d = os.path.join(t, f"s{i}")
        work = os.path.join(d, "work")
        os.makedirs(work)
        md = os.path.join(d, name)
        os.makedirs(md)
        m = os.path.join(md, "m.toml")
        open(m, "w").write('name = "t"\n')
        out = os.path.join(d, "run")
        rc, _, err = run(["slurm", "bench", m, "--array", "2", "--out", out])
        if rc is None or "panicked" in err:
            record("A scripts", repr(name), False, err[-200:])
            continue
        if rc != 0:
            ok = "control character" in err
            record("A scripts", repr(name), ok, "refused without naming the character: " + err[-200:])
            continue
        ok, why = True, ""
        for s in ["array.sbatch", "merge.sbatch"]:
            p = os.path.join(out, s)
            lines = open(p, encoding="utf-8", errors="replace").read().split("\n")
            if any(l and not (l.startswith("#") or l.startswith("exec ")) for l in lines):
                ok, why = False, f"{s} has a line that is neither comment nor exec"
            subprocess.run(["bash", p], cwd=work, capture_output=True, timeout=20, env=ENV)
            if os.listdir(work):
                ok, why = False, f"{s} created {os.listdir(work)}"
        record("A scripts", repr(name), ok, why)
    # Slurm option values and the run folder
    for opt, val in [
        ("--partition", "gpu\nrm -rf x"), ("--gres", "gpu:1;touch MARK"), ("--time", "$(x)"),
        ("--mem", "1G\r\n#SBATCH --x"), ("--account", "a b"), ("--out", "run\nx"),
        ("--out", "run'x"), ("--out", "run$(x)"),
    ]:
        d = tempfile.mkdtemp(dir=t)
        m = os.path.join(d, "m.toml")
        open(m, "w").write('name = "t"\n')
        args = ["slurm", "bench", m, "--array", "2"]
        args += [opt, val] if opt == "--out" else ["--out", os.path.join(d, "run"), opt, val]
        rc, _, err = run(args)
        record("A scripts", f"{opt} {val!r}", rc not in (0, None) and "panicked" not in err, err[-200:])


# ------------------------------------------------------------------ B. outputs
def pass_outputs(t):
    shards_dir = os.path.join(t, "runB")
    three_shards(shards_dir)
    cmds = {
        "merge --json": lambda o, f: ["merge", shards_dir, "--json", o] + f,
        "register --export-corr": lambda o, f: [
            "register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--no-cache",
            "--voxel", "0.3", "--export-corr", o] + f,
        "bench --json": lambda o, f: ["bench", DEMO, "--no-cache", "--voxel", "0.3", "--json", o] + f,
        "generate --json": lambda o, f: [
            "generate", DEMO, "--wfm", "oracle", "--cache-dir", os.path.join(t, "cacheB"), "--json", o] + f,
        "study k --json": lambda o, f: [
            "study", "k", DEMO, "--wfm", "oracle", "--no-cache", "--json", o] + f,
        "screenshot --out": lambda o, f: ["screenshot", "--panel", "pairs", "--out", o] + f,
    }
    for cname, mk in cmds.items():
        d = tempfile.mkdtemp(dir=t)
        victim = os.path.join(d, "victim.txt")
        open(victim, "w").write("keep me")
        vdir = os.path.join(d, "vdir")
        os.mkdir(vdir)
        targets = {}
        p = os.path.join(d, "fifo")
        os.mkfifo(p)
        targets["FIFO"] = p
        p = os.path.join(d, "link-file")
        os.symlink(victim, p)
        targets["link to a file"] = p
        p = os.path.join(d, "link-dir")
        os.symlink(vdir, p)
        targets["link to a folder"] = p
        p = os.path.join(d, "dangling")
        os.symlink(os.path.join(d, "nowhere"), p)
        targets["dangling link"] = p
        targets["folder"] = vdir
        targets["foreign file"] = victim
        targets["missing folder"] = os.path.join(d, "no", "such", "out")
        try:
            p = os.path.join(d, "fullnode")
            os.mknod(p, 0o600 | stat.S_IFCHR, os.makedev(1, 7))
            targets["character device"] = p
        except (PermissionError, OSError):
            pass
        p = os.path.join(d, "zero-link")
        os.symlink("/dev/zero", p)
        targets["link to /dev/zero"] = p
        for tname, target in targets.items():
            for force in ([], ["--force"]):
                before = {x: kind(x) for x in [target, victim, vdir]}
                rc, _, err = run(mk(target, force), timeout=60)
                after = {x: kind(x) for x in [target, victim, vdir]}
                name = f"{cname} -> {tname} {' '.join(force)}"
                if tname == "foreign file" and force:
                    # --force replaces a regular file: allowed
                    ok = rc is not None and "panicked" not in err
                    record("B outputs", name, ok, err[-200:])
                    continue
                ok = (
                    rc not in (0, None)
                    and "panicked" not in err
                    and before == after
                    and not os.path.exists(os.path.join(d, "no"))
                    and not tmp_left(d)
                )
                record("B outputs", name, ok, f"rc={rc} changed={before != after} {err[-200:]}")


# ------------------------------------------------------------------ C. run-file readers
def pass_readers(t):
    deep = "[" * 100000
    bad = {
        "/dev/zero link": None,
        "FIFO": None,
        "folder": None,
        "truncated": b'{"run": {"identity": ',
        "empty": b"",
        "BOM": b"\xef\xbb\xbf" + json.dumps(run_file(1, 3, 3, 6, ["t/p1"])).encode(),
        "deeply nested": deep.encode(),
        "not JSON": b"hello",
        "NUL bytes": b"\0" * 100,
        "not UTF-8": b'{"run": "\xff\xfe"}',
        "wrong types": b'{"run": 3, "records": "x"}',
        "records not an array": json.dumps(dict(run_file(1, 3, 3, 6, []), records={})).encode(),
        "duplicated records": json.dumps(run_file(1, 3, 3, 6, ["t/p1", "t/p1"])).encode(),
        "shard out of range": json.dumps(run_file(7, 3, 3, 6, [])).encode(),
        "1-shard claim": json.dumps(run_file(0, 1, 3, 6, [])).encode(),
        "shard count 0": json.dumps(run_file(0, 0, 0, 6, [])).encode(),
        "record of another shard": json.dumps(run_file(1, 3, 3, 6, ["t/p2"])).encode(),
        "record outside the selection": json.dumps(run_file(1, 3, 3, 6, ["t/zzz"])).encode(),
        "huge number": json.dumps(run_file(1, 3, 3, 6, [])).replace('"index": 1', '"index": 1e400').encode(),
        "negative index": json.dumps(run_file(1, 3, 3, 6, [])).replace('"index": 1', '"index": -1').encode(),
        "oversized": b" " * 5000 + json.dumps(run_file(1, 3, 3, 6, ["t/p1"])).encode(),
    }
    readers = {
        "status FILE": lambda p, d: ["status", p],
        "status DIR": lambda p, d: ["status", d],
        "merge FILE": lambda p, d: ["merge", p],
        "merge DIR": lambda p, d: ["merge", d],
        "table": lambda p, d: ["table", p],
        "diff": lambda p, d: ["diff", p, p],
        "screenshot --compare": lambda p, d: [
            "screenshot", "--panel", "compare", "--compare", p, p, "--out", os.path.join(d, "c.png")],
        "bench resume": lambda p, d: ["bench", DEMO, "--no-cache", "--json", p, "--force"],
        "generate resume": lambda p, d: [
            "generate", DEMO, "--wfm", "oracle", "--cache-dir", os.path.join(d, "cache"), "--json", p, "--force"],
    }
    for bname, content in bad.items():
        for rname, mk in readers.items():
            d = tempfile.mkdtemp(dir=t)
            three_shards(d)
            p = os.path.join(d, "shards", "shard-1.json")
            os.remove(p)
            if bname == "/dev/zero link":
                os.symlink("/dev/zero", p)
            elif bname == "FIFO":
                os.mkfifo(p)
            elif bname == "folder":
                os.mkdir(p)
            else:
                open(p, "wb").write(content)
            env = dict(ENV)
            if bname == "oversized":
                env["CGENREG_MAX_RUN_FILE_BYTES"] = "4000"
            rc, out, err = run(mk(p, d), timeout=30, env=env)
            name = f"{rname} <- {bname}"
            both = out + err
            ok = (
                rc not in (0, None)
                and "panicked" not in err
                and "shard-1.json" in both
                and "18446744073709551615" not in both
            )
            if rname.startswith("status") and "| 1/3 | (no output yet)" in out:
                ok = False
            record("C readers", name, ok, f"rc={rc} {err[-240:]}")


# ------------------------------------------------------------------ D. stdout
def pass_stdout(t):
    d = os.path.join(t, "runD")
    three_shards(d)
    cache = os.path.join(t, "cacheD")
    subprocess.run([BIN, "cache", "--dir", cache, "init"], capture_output=True, env=ENV)
    cmds = {
        "bench --list": ["bench", DEMO, "--list"],
        "status": ["status", d],
        "merge": ["merge", d],
        "cache list": ["cache", "--dir", cache, "list"],
        "cache verify": ["cache", "--dir", cache, "verify"],
        "table": ["table", os.path.join(d, "shards", "shard-0.json")],
        "register": ["register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--no-cache", "--voxel", "0.3"],
        "register --json": ["register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--no-cache", "--voxel", "0.3", "--json"],
        "slurm": ["slurm", "bench", DEMO, "--array", "2", "--out", os.path.join(t, "slD")],
        "--help": ["--help"],
    }
    for cname, args in cmds.items():
        r, w = os.pipe()
        os.close(r)
        rc, _, err = run(args, stdout=w, timeout=60)
        os.close(w)
        # a command that itself fails (table on a generate file) keeps its own status
        record("D stdout", cname + " | closed pipe", rc is not None and "panicked" not in err
               and (rc == 0 or "error" in err), f"rc={rc} {err[-200:]}")
        with open("/dev/full", "w") as full:
            rc, _, err = run(args, stdout=full, timeout=60)
        printed = cname not in ("cache list", "cache verify")
        ok = rc is not None and "panicked" not in err and (not printed or rc != 0)
        record("D stdout", cname + " > /dev/full", ok, f"rc={rc} {err[-200:]}")


with tempfile.TemporaryDirectory() as t:
    for f in (pass_scripts, pass_outputs, pass_readers, pass_stdout):
        sub = os.path.join(t, f.__name__)
        os.makedirs(sub)
        f(sub)

for f in failures:
    print("FAIL", f)
total = sum(c[0] for c in counts.values())
for cls, (n, ok) in counts.items():
    print(f"{cls}: {ok}/{n} as required")
print(f"total: {total - len(failures)}/{total} as required")
sys.exit(1 if failures else 0)
