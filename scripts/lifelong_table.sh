#!/usr/bin/env bash
# LIBERO's table of lifelong algorithms for one suite, from one command: `elegant lifelong` once per
# algorithm (SeqL, ER, EWC, PackNet, multitask) into OUT/<algo>, then `elegant lifelong-table` into
# OUT/table. Every further option (--tasks or --task-order, --seeds, --epochs, --episodes, --workers,
# --resume, ...) goes to each `elegant lifelong` run unchanged.
#
# JOBS=N runs N algorithms at a time, each logging to OUT/<algo>.log (a failed one's last line is printed).
# With --workers 1 each evaluation runs in its algorithm's own process, so no worker processes start
# per evaluation: on C cores, JOBS=C --workers 1 is the fastest way through the table.
#
#   [JOBS=N] bash scripts/lifelong_table.sh SUITE DEMOS.hdf5 OUT [OPTIONS...]
set -euo pipefail
if [ "$#" -lt 3 ]; then
    echo "usage: [JOBS=N] bash scripts/lifelong_table.sh SUITE DEMOS.hdf5 OUT [elegant lifelong options...]" >&2
    exit 2
fi
suite=$1 demos=$2 out=$3
shift 3
elegant=${ELEGANT:-elegant}
jobs=${JOBS:-1}
if ! [[ "$jobs" =~ ^[1-9][0-9]*$ ]]; then
    echo "JOBS: expected a whole number >= 1, got '$jobs'" >&2
    exit 2
fi
algos=(seql er ewc packnet multitask)
if [ "$jobs" -eq 1 ]; then
    for algo in "${algos[@]}"; do
        $elegant lifelong --suite "$suite" "$demos" --out "$out/$algo" --algo "$algo" "$@"
    done
else
    fresh=0
    [ -e "$out" ] || fresh=1
    mkdir -p "$out"
    # shellcheck disable=SC2016  # $1.. are the inner shell's: the algorithm, then the command
    if ! printf '%s\n' "${algos[@]}" | xargs -P "$jobs" -I{} sh -c \
        'a=$1 o=$2; shift 2; "$@" --out "$o/$a" --algo "$a" > "$o/$a.log" 2>&1 || { echo "$a: $(tail -n 1 "$o/$a.log")" >&2; exit 1; }' \
        _ {} "$out" $elegant lifelong --suite "$suite" "$demos" "$@"; then
        if [ "$fresh" -eq 1 ] && ! compgen -G "$out/*/" > /dev/null; then
            rm -rf "$out"  # every algorithm refused before writing: leave nothing behind
        else
            echo "lifelong_table.sh: an algorithm failed (its log: $out/<algo>.log)" >&2
        fi
        exit 1
    fi
fi
$elegant lifelong-table "${algos[@]/#/$out/}" --out "$out/table" --overwrite
