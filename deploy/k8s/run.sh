#!/usr/bin/env bash
# Fit a stored capture on Kubernetes in N tiles and a merge:
#
#   deploy/k8s/run.sh [--dry-run] [--image IMAGE] CAPTURE N
#
# CAPTURE is the capture's path inside the pods (on the volume claimed as
# `reflectometer-captures`, mounted at /captures). It applies
# fit-tiles.yaml with CAPTURE and N filled in (an Indexed Job of N pods,
# pod K running `refl fit CAPTURE --tile K/N`), waits for it to complete,
# then applies fit-merge.yaml (`refl fit CAPTURE --merge`) and waits for
# that. IMAGE (default reflectometer:latest) must hold `refl` on its PATH
# (deploy/k8s/Dockerfile builds one). --dry-run prints the two manifests
# as they would be applied and touches no cluster.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
dry=0
image=reflectometer:latest
while [ $# -gt 0 ]; do
  case "$1" in
    --dry-run) dry=1; shift ;;
    --image) image="$2"; shift 2 ;;
    *) break ;;
  esac
done
[ $# -eq 2 ] || { sed -n 2,14p "$0" >&2; exit 2; }
capture="$1"
tiles="$2"
case "$tiles" in ''|*[!0-9]*|0) echo "run: N must be a whole number of tiles, at least 1 (got '$tiles')" >&2; exit 2 ;; esac
case "$capture" in /*) ;; *) echo "run: CAPTURE must be the capture's absolute path inside the pods" >&2; exit 2 ;; esac
# Fill in the manifests' CAPTURE, TILES, completions, parallelism and image.
fill() {
  python3 - "$1" "$capture" "$tiles" "$image" <<'PY'
import sys
path, capture, tiles, image = sys.argv[1:]
out, env = [], None
for line in open(path):
    s = line.strip()
    indent = line[: len(line) - len(line.lstrip())]
    if s.startswith("- name: "):
        env = s[len("- name: "):]
    if s.startswith("completions:") or s.startswith("parallelism:"):
        line = f"{indent}{s.split(':')[0]}: {tiles}\n"
    elif s.startswith("image:"):
        line = f"{indent}image: {image}\n"
    elif s.startswith("value:") and env == "CAPTURE":
        line = f"{indent}value: {capture}\n"
    elif s.startswith("value:") and env == "TILES":
        line = f'{indent}value: "{tiles}"\n'
    out.append(line)
sys.stdout.write("".join(out))
PY
}
if [ "$dry" = 1 ]; then
  fill "$here/fit-tiles.yaml"
  echo "---"
  fill "$here/fit-merge.yaml"
  exit 0
fi
kubectl delete job refl-fit-tiles refl-fit-merge --ignore-not-found
fill "$here/fit-tiles.yaml" | kubectl apply -f -
kubectl wait --for=condition=complete job/refl-fit-tiles --timeout=24h
fill "$here/fit-merge.yaml" | kubectl apply -f -
kubectl wait --for=condition=complete job/refl-fit-merge --timeout=24h
echo "run: $capture fitted in $tiles tiles; its material is in $capture/material"
