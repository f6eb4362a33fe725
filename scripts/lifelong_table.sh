#!/usr/bin/env bash
# LIBERO's table of lifelong algorithms for one suite, from one command: `elegant lifelong` once per
# algorithm (SeqL, ER, EWC, PackNet, multitask) into OUT/<algo>, then `elegant lifelong-table` into
# OUT/table. Every further option (--tasks or --task-order, --seeds, --epochs, --episodes, --workers,
# --resume, ...) goes to each `elegant lifelong` run unchanged.
#
#   bash scripts/lifelong_table.sh SUITE DEMOS.hdf5 OUT [OPTIONS...]
set -euo pipefail
if [ "$#" -lt 3 ]; then
    echo "usage: bash scripts/lifelong_table.sh SUITE DEMOS.hdf5 OUT [elegant lifelong options...]" >&2
    exit 2
fi
suite=$1 demos=$2 out=$3
shift 3
elegant=${ELEGANT:-elegant}
algos=(seql er ewc packnet multitask)
for algo in "${algos[@]}"; do
    $elegant lifelong --suite "$suite" "$demos" --out "$out/$algo" --algo "$algo" "$@"
done
$elegant lifelong-table "${algos[@]/#/$out/}" --out "$out/table" --overwrite
