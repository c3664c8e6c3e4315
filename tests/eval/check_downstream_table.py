"""bench/eval/downstream_table.py on CSVs whose answer is known: ours is
real - 1 deg and warp + 0.5 deg for every identity (differences -1.00
and -1.50 with intervals of zero width, -11.8 % at the mean real 8.45), the rows of
two runs over disjoint identities pool, a k missing a condition for an
identity leaves that identity out at that k, and an identity in two runs
is refused. usage: check_downstream_table.py SCRIPT"""
import os
import subprocess
import sys
import tempfile


def write(d, ids, drop=None):
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "downstream.csv"), "w") as f:
        f.write("identity,identity_seed,k,condition,gaze_err_deg\n")
        for i in ids:
            for k in (0, 1, 3):
                real = 8.0 + (0.1 * i if k else 0.0)
                vals = {"real": real, "real+ours": real - (1.0 if k else 0),
                        "real+warp": real + (0.5 if k else 0)}
                for c, v in vals.items():
                    if drop == (i, k, c):
                        continue
                    f.write(f"{i},{1000 + i},{k},{c},{v:.4f}\n")


def run(script, *dirs):
    return subprocess.run([sys.executable, script, *dirs, "--reps", "500"],
                          capture_output=True, text=True)


def main():
    script = sys.argv[1]
    fails = 0
    with tempfile.TemporaryDirectory() as t:
        a, b, c = (os.path.join(t, n) for n in "abc")
        write(a, range(0, 5))
        write(b, range(5, 10), drop=(7, 3, "real+warp"))
        write(c, range(4, 6))
        r = run(script, a, b)
        rows = {line.split("|")[1].strip(): line for line in
                r.stdout.splitlines() if line.startswith("| ")}

        def want(cond, text):
            nonlocal fails
            if not cond:
                print("FAIL:", text, "\n", r.stdout, r.stderr)
                fails += 1
        want(r.returncode == 0, "exit status")
        want("| 10 |" in rows.get("1", ""), "k=1 pools 10 people")
        want("| 9 |" in rows.get("3", ""), "k=3 leaves out the identity "
             "without a warp row")
        want("-1.00 (-1.00 to -1.00)" in rows.get("1", ""), "ours - real")
        want("-1.50 (-1.50 to -1.50)" in rows.get("1", ""), "ours - warp")
        # real at k=1: mean of 8 + 0.1 i over i = 0..9 = 8.45; -1/8.45
        want("-11.8 %" in rows.get("1", ""), "relative change")
        r = run(script, a, c)
        want(r.returncode != 0 and "identity 4" in r.stderr,
             "an identity in two runs")
    sys.exit(1 if fails else 0)


if __name__ == "__main__":
    main()
