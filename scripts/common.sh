# Shared by the measurement scripts (sourced from the repository root).

# Set `bin` to this tree's release build (set-up and build first) unless a
# `--bin DIR` already set it.
release_bins() {
  if [ -z "$bin" ]; then
    bash scripts/setup.sh
    cargo build --release --quiet --bins
    bin="$PWD/target/release"
  fi
}

# Create directory $1 and print its absolute path.
absolute_dir() {
  mkdir -p "$1"
  (cd "$1" && pwd)
}
