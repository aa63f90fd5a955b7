# Shared by the tools/bench_vs_*.sh scripts (sourced, not run): finding the
# fluxgraph binary, checking a count that the two-size timing divides by 4,
# and a scratch directory removed on exit. Each function prints one line
# naming the calling script and exits with code 2 on bad input.

# Sets `fluxgraph` to BUILD/fluxgraph, relative to the working directory or to the repository root.
bench_find_fluxgraph() {  # SCRIPT BUILD ROOT
  fluxgraph="$2/fluxgraph"
  [ -x "$fluxgraph" ] || fluxgraph="$3/$2/fluxgraph"
  if [ ! -x "$fluxgraph" ]; then
    echo "$1: no fluxgraph binary in $2 (build it first)" >&2
    exit 2
  fi
}

# Each benchmark times COUNT and COUNT / 4 and divides the difference, so start-up cancels.
bench_require_multiple_of_four() {  # SCRIPT OPTION COUNT
  case "$3" in
    ''|*[!0-9]*) echo "$1: $2 must be a positive multiple of 4" >&2; exit 2 ;;
  esac
  if [ $(($3 % 4)) -ne 0 ] || [ "$3" -lt 4 ]; then
    echo "$1: $2 must be a positive multiple of 4" >&2
    exit 2
  fi
}

# Sets `work` to a fresh directory that is removed when the script exits.
bench_make_work_dir() {
  work="$(mktemp -d)"
  trap 'rm -rf "$work"' EXIT
}
