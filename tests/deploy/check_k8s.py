#!/usr/bin/env python3
"""Check deploy/k8s: both manifests parse as YAML (PyYAML), describe what
the fit in tiles needs, and run.sh fills them in consistently.

    python3 tests/deploy/check_k8s.py

For N in 1, 3 and 16 tiles, `deploy/k8s/run.sh --dry-run` must give an
Indexed Job of N completions and N pods at once whose TILES is N and
whose command runs `refl fit CAPTURE --tile $JOB_COMPLETION_INDEX/$TILES`,
then a Job running `refl fit CAPTURE --merge`, both with the same capture
path on the same claim, the pod's CPUs as rayon's threads, and pods that
are not restarted in place (a failed tile is retried as a new pod).
"""
import os
import subprocess
import sys

import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def env_of(container):
    return {e["name"]: e.get("value") for e in container.get("env", [])}


def check(capture, tiles):
    out = subprocess.run(
        ["bash", os.path.join(ROOT, "deploy/k8s/run.sh"), "--dry-run", "--image", "example/refl:1", capture, str(tiles)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    docs = [d for d in yaml.safe_load_all(out) if d is not None]
    assert len(docs) == 2, f"two manifests, got {len(docs)}"
    tiles_job, merge_job = docs
    for job in docs:
        assert job["apiVersion"] == "batch/v1" and job["kind"] == "Job", job.get("kind")
        pod = job["spec"]["template"]["spec"]
        assert pod["restartPolicy"] == "Never", pod["restartPolicy"]
        (c,) = pod["containers"]
        assert c["image"] == "example/refl:1", c["image"]
        env = env_of(c)
        assert env["CAPTURE"] == capture, env
        cpus = c["resources"]["requests"]["cpu"]
        assert env["RAYON_NUM_THREADS"] == str(cpus), (env, cpus)
        mounts = {m["name"]: m["mountPath"] for m in c["volumeMounts"]}
        claims = {v["name"]: v["persistentVolumeClaim"]["claimName"] for v in pod["volumes"]}
        assert mounts == {"captures": "/captures"} and claims == {"captures": "reflectometer-captures"}
        assert capture.startswith(mounts["captures"] + "/"), "the capture lies on the mounted claim"
    spec = tiles_job["spec"]
    assert spec["completionMode"] == "Indexed"
    assert spec["completions"] == tiles and spec["parallelism"] == tiles, spec
    (c,) = spec["template"]["spec"]["containers"]
    assert env_of(c)["TILES"] == str(tiles)
    cmd = " ".join(c["command"])
    assert 'refl fit "$CAPTURE" --tile "$JOB_COMPLETION_INDEX/$TILES"' in cmd, cmd
    (c,) = merge_job["spec"]["template"]["spec"]["containers"]
    cmd = " ".join(c["command"])
    assert 'refl fit "$CAPTURE" --merge' in cmd and "--tile" not in cmd, cmd
    assert "completionMode" not in merge_job["spec"]


def main():
    for path in ["deploy/k8s/fit-tiles.yaml", "deploy/k8s/fit-merge.yaml"]:
        with open(os.path.join(ROOT, path)) as f:
            yaml.safe_load(f)
    for tiles in [1, 3, 16]:
        check("/captures/lab/satin-2026", tiles)
    for bad in [["/captures/x", "0"], ["relative/x", "2"], ["/captures/x", "two"]]:
        r = subprocess.run(["bash", os.path.join(ROOT, "deploy/k8s/run.sh"), "--dry-run", *bad], capture_output=True)
        assert r.returncode == 2, (bad, r.returncode)
    print("check_k8s: deploy/k8s manifests and run.sh checked", file=sys.stderr)


if __name__ == "__main__":
    main()
