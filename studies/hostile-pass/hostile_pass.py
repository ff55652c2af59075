#!/usr/bin/env python3
"""A hostile pass over cgenreg's output files, run-file readers, stdout, the paths that go
into Slurm scripts, and the later surfaces (code in the working directory, outputs judged by
cgenreg's marker, manifests, inputs, option values, concurrent runs), through the real binary. Prints one line per failed case and the counts
per class; exits 1 when a case fails.

    python3 studies/hostile-pass/hostile_pass.py target/debug/cgenreg

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
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
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


# ------------------------------------------------------------------ E. the later surfaces
def pass_surfaces(t):
    """Planted code in the working directory, outputs judged by cgenreg's marker, manifests
    (size, root, ids, confinement), inputs that are FIFOs, numeric options' errors, two
    processes on one run file."""
    import zipfile
    import zlib
    import struct

    # E1: planted onnxruntime.py / onnxruntime/ / python3 with "." on PATH
    cwd = os.path.join(t, "planted")
    os.makedirs(os.path.join(cwd, "onnxruntime"))
    marks = [os.path.join(cwd, m) for m in ("M1", "M2", "M3")]
    open(os.path.join(cwd, "onnxruntime.py"), "w").write(f"open({marks[0]!r}, 'w')\n")
    open(os.path.join(cwd, "onnxruntime", "__init__.py"), "w").write(f"open({marks[1]!r}, 'w')\n")
    py3 = os.path.join(cwd, "python3")
    open(py3, "w").write(f"#!/bin/sh\ntouch '{marks[2]}'\n")
    os.chmod(py3, 0o755)
    env = dict(ENV, PATH=".::" + ENV.get("PATH", ""))
    for args in (["register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--wfm", "builtin",
                  "--frames", "8", "--margin", "1", "--k", "2", "--voxel", "0.3", "--no-cache"],
                 ["register", "--source", "nope.ply", "--target", "nope.ply", "--wfm", "builtin"]):
        rc, _, err = run(args, timeout=120, env=env, cwd=cwd)
        ran = [m for m in marks if os.path.exists(m)]
        record("E surfaces", "planted code in cwd: " + args[1], rc is not None and not ran,
               f"ran {ran} rc={rc} {err[-200:]}")

    # E2: files of the output's container format that cgenreg did not write
    d = os.path.join(t, "foreign")
    os.makedirs(d)

    def png_bytes():
        raw = b"\x00\x00\x00\x00"
        ch = lambda k, x: struct.pack(">I", len(x)) + k + x + struct.pack(">I", zlib.crc32(k + x))
        return (b"\x89PNG\r\n\x1a\n" + ch(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0))
                + ch(b"IDAT", zlib.compress(raw[:2])) + ch(b"IEND", b""))

    foreign = {}
    foreign["a figure (PNG)"] = ("fig.png", png_bytes())
    z = os.path.join(t, "z.zip")
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("word/document.xml", "<w/>")
    foreign["a .docx (ZIP)"] = ("doc.npz", open(z, "rb").read())
    foreign["JSON with a run key"] = ("run.json", b'{"run": {"mine": 1}, "records": []}')
    foreign["JSON like a result"] = ("res.json", b'{"pair_id": "x"}')
    foreign["a text file"] = ("notes.txt", b"keep me")
    outs = {
        "screenshot --out": lambda o: ["screenshot", "--panel", "pairs", "--out", o],
        "screenshot --result-json": lambda o: [
            "screenshot", "--panel", "pairs", "--out", os.path.join(d, "new.png"), "--result-json", o],
        "register --export-corr": lambda o: [
            "register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--voxel", "0.3",
            "--no-cache", "--export-corr", o],
        "bench --json": lambda o: ["bench", DEMO, "--voxel", "0.3", "--no-cache", "--json", o],
    }
    for cname, mk in outs.items():
        for fname, (name, data) in foreign.items():
            p = os.path.join(d, name)
            with open(p, "wb") as f:
                f.write(data)
            rc, _, err = run(mk(p), timeout=60)
            same = open(p, "rb").read() == data
            record("E surfaces", f"{cname} -> {fname}",
                   rc not in (0, None) and same and "panicked" not in err and not tmp_left(d),
                   f"rc={rc} same={same} {err[-200:]}")

    # E3: manifests
    m = os.path.join(t, "manifests")
    os.makedirs(m)
    open(os.path.join(m, "a.xyz"), "w").write("0 0 0\n1 0 0\n0 1 0\n0 0 1\n")
    head = 'name = "m"\n[[fragments]]\nid = "a"\ncloud = "a.xyz"\n[[fragments]]\nid = "b"\ncloud = "a.xyz"\n'
    cases = {
        "a 60 MB gt_matrix": (head + '[[pairs]]\ntarget = "a"\nsource = "b"\ngt_matrix = ['
                              + "[1.0, 0.0, 0.0, 0.0], " * 2_800_000 + "]\n", "file size"),
        'root = "/"': ('root = "/"\n' + head, "confines nothing"),
    }
    for i, bad in enumerate(["\\u001b[2J", "a\\u0000b", "a\\nb", "a\\rb", "a\\u202eb",
                             "a\\u200bb", "a\\u0085b", "a\\u007fb", "x" * 300]):
        cases[f"id {bad[:12]}"] = (f'name = "m"\n[[fragments]]\nid = "{bad}"\ncloud = "a.xyz"\n', ".id")
        cases[f"split {bad[:12]}"] = (head + f'[[pairs]]\ntarget = "a"\nsource = "b"\nsplit = "{bad}"\n',
                                      ".split" if len(bad) < 300 else None)
    for cname, (text, want) in cases.items():
        if want is None:
            continue
        p = os.path.join(m, "m.toml")
        open(p, "w").write(text)
        rc, _, err = run(["bench", p, "--list"], timeout=30)
        raw = any(c in err for c in ("\x1b", "\x00", "\u202e", "\u200b", "\x85", "\x7f"))
        record("E surfaces", "manifest: " + cname,
               rc not in (0, None) and want in err and not raw and "panicked" not in err,
               f"rc={rc} raw={raw} {err[-200:]}")

    # E4: inputs that are FIFOs where the readers' own checks did not reach
    f = os.path.join(t, "inputs")
    os.makedirs(f)
    fifo = os.path.join(f, "fifo.onnx")
    os.mkfifo(fifo)
    for cname, args in {
        "--vfm-model FIFO": ["register", "--manifest", DEMO, "--pair", "synth-room/0-1", "--wfm",
                             "builtin", "--frames", "8", "--margin", "1", "--k", "2", "--voxel", "0.3",
                             "--no-cache", "--vfm-model", fifo],
        "--gt FIFO": ["register", "--source", os.path.join(m, "a.xyz"), "--target",
                      os.path.join(m, "a.xyz"), "--gt", fifo],
        "--source FIFO": ["register", "--source", fifo, "--target", os.path.join(m, "a.xyz")],
        "--manifest /dev/zero": ["bench", "/dev/zero", "--list"],
    }.items():
        rc, _, err = run(args, timeout=30)
        record("E surfaces", "input: " + cname, rc not in (0, None) and "panicked" not in err,
               f"rc={rc} {err[-200:]}")

    # E5: neighbouring values of numeric options: all exit 2 with "must be"
    for opt, values in {
        "--frames": ["-1", "0", "1.5", "x", "1001"], "--k": ["-1", "0", "1e3"],
        "--topk": ["-1", "0", "1" + "0" * 30], "--margin": ["-1", "0.5"],
        "--tau-img": ["-1", "0", "nan", "inf", "-inf", "1e-50"], "--tau-geo": ["0", "nan"],
        "--prior": ["-1", "0", "1", "2", "nan"], "--voxel": ["-0.05", "0", "nan", "1e400"],
    }.items():
        for v in values:
            rc, _, err = run(["register", "--source", "a.ply", "--target", "b.ply", opt, v], timeout=10)
            record("E surfaces", f"option {opt} {v}",
                   rc == 2 and opt in err and ("must be" in err or "exceeds" in err),
                   f"rc={rc} {err[-200:]}")

    # E6: two processes given one run file
    j = os.path.join(t, "two", "run.json")
    os.makedirs(os.path.dirname(j))
    args = [BIN, "bench", DEMO, "--voxel", "0.1", "--no-cache", "--json", j]
    first = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV)
    import time
    time.sleep(0.5)
    second = subprocess.run(args, capture_output=True, env=ENV, timeout=120)
    first_err = first.communicate(timeout=120)[1]
    rcs = sorted([first.returncode, second.returncode])
    both = (first_err + second.stderr).decode(errors="replace")
    record("E surfaces", "two processes, one --json",
           rcs[0] == 0 and rcs[1] != 0 and "another running cgenreg process" in both,
           f"rcs={rcs} {both[-300:]}")


with tempfile.TemporaryDirectory() as t:
    for f in (pass_scripts, pass_outputs, pass_readers, pass_stdout, pass_surfaces):
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
