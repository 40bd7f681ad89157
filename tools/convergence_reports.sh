#!/usr/bin/env bash
# Regenerates the accuracy/time reports of docs/convergence.md: runs `kelvin converge` with --plot and copies
# the figures into docs/img/convergence_<report>_*.png (the tables are in <OUT>/<report>/plots/*.md).
#
#   tools/convergence_reports.sh fluid-nmc      # Taylor–Green RMSE vs n_mc at t = 0.25, 0.5, 1 (like Fig. 5.15)
#   tools/convergence_reports.sh fluid-cells    #   ... vs cache cells
#   tools/convergence_reports.sh fluid-dt       #   ... vs dt
#   tools/convergence_reports.sh fluid-params   # one degraded parameter at a time (like Fig. 5.9)
#   tools/convergence_reports.sh fluid-visual   #   ... on a moving vortex dipole against a reference run, images
#   tools/convergence_reports.sh fluid-baselines  # MCFluid, vortex particles and stable fluids vs resolution
#   tools/convergence_reports.sh mlt            # the MLT family at equal time (MLT_REF=reference.exr, MLT_GEOMETRY)
#   tools/convergence_reports.sh all            # the six fluid reports
#
# Environment: KELVIN (default build/bin/kelvin), OUT (default /tmp/kelvin-convergence; studies there are
# resumed, FRESH=1 deletes them first), RUNS (independent runs, default 3), THREADS (default: all cores).
set -euo pipefail
cd "$(dirname "$0")/.."

KELVIN=${KELVIN:-build/bin/kelvin}
OUT=${OUT:-/tmp/kelvin-convergence}
RUNS=${RUNS:-3}
THREADS=${THREADS:-0}
TG=scenes/fluid/taylor_green.xml

converge() {  # converge REPORT ARGS...: run (or resume) the study into $OUT/REPORT, with plots
    local report=$1
    shift
    [[ "${FRESH:-0}" == 1 ]] && rm -rf "${OUT:?}/$report"
    "$KELVIN" converge "$@" --runs "$RUNS" -t "$THREADS" -o "$OUT/$report" --plot
}

figures() {  # figures REPORT PLOT...: copy plots into docs/img
    local report=$1
    shift
    for f in "$@"; do cp "$OUT/$report/plots/$f" "docs/img/convergence_${report//-/_}_$f"; done
    echo "== $report: $OUT/$report/plots/summary.md"
    cat "$OUT/$report/plots/summary.md"
}

configs() {  # configs NAME DEFINE V1 V2 ...: --config NAME=V:DEFINE=V for each value
    local name=$1 define=$2
    shift 2
    for v in "$@"; do printf -- '--config\n%s=%s:%s=%s\n' "$name" "$v" "$define" "$v"; done
}

report() {
    case "$1" in
    fluid-nmc)
        mapfile -t c < <(configs n_mc spp 16 64 256 1024)
        converge fluid-nmc "$TG" -D res=64 -D dt=0.05 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-nmc error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-cells)
        mapfile -t c < <(configs nx res 16 32 64 128)
        converge fluid-cells "$TG" -D spp=256 -D dt=0.05 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-cells error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-dt)
        mapfile -t c < <(configs dt dt 0.25 0.125 0.0625 0.03125 0.015625)
        converge fluid-dt "$TG" -D res=64 -D spp=256 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-dt error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-params)
        converge fluid-params "$TG" -D res=64 -D spp=256 -D dt=0.05 -D end=2 --times 0.5,1,2 \
            --config "baseline:" --config "nearest:interpolation=nearest" --config "kernel IS:importance=kernel" \
            --config "uniform:importance=uniform" --config "dt 0.2:dt=0.2" --config "32^2 cells:res=32" \
            --config "n_mc 64:spp=64" --config "euler:advection=euler"
        figures fluid-params error_vs_seconds_rmse.png error_vs_seconds_max_abs.png ;;
    fluid-visual)
        # One degraded parameter at a time on a moving flow (a vortex dipole), against a fine reference run at
        # t = 2 (computed once, kept in $OUT): errors, and the fields side by side.
        local ps=scenes/fluid/parameter_study.xml ref="$OUT/fluid-visual-reference.exr"
        mkdir -p "$OUT"
        [[ -f "$ref" ]] || "$KELVIN" "$ps" -D res=128 -D spp=1024 -D dt=0.025 --seed 1000 -t "$THREADS" -q -o "$ref"
        converge fluid-visual "$ps" --reference "$ref" --times 2 \
            --config "baseline:" --config "nearest:interpolation=nearest" --config "kernel IS:importance=kernel" \
            --config "uniform:importance=uniform" --config "dt 0.2:dt=0.2" --config "32^2 cells:res=32" \
            --config "n_mc 64:spp=64" --config "euler:advection=euler"
        /usr/bin/python3 tools/plot_convergence.py "$OUT/fluid-visual/convergence.csv" --crop 0.2,0.25,0.6,0.6 >/dev/null
        figures fluid-visual grid.png error_vs_seconds_rmse.png ;;
    fluid-baselines)
        c=()
        for s in mcfluid vortex_particles stable_fluids; do
            for r in 16 32 64; do c+=(--config "$s res=$r:solver=$s,res=$r"); done
        done
        converge fluid-baselines "$TG" -D spp=256 -D dt=0.05 -D end=1 "${c[@]}" --times 0.5,1
        figures fluid-baselines error_vs_cost_rmse.png error_vs_param_rmse.png ;;
    mlt)
        # The MLT family at equal time on one of the project's hard scenes: scenes/render/mlt-study.xml picks the
        # variant (scenes/render/mlt-study.configs, one configuration each) and the geometry (MLT_GEOMETRY: door or
        # caustic). MLT_REF is a long reference render of the same geometry and resolution.
        local geometry=${MLT_GEOMETRY:-door}
        : "${MLT_REF:?set MLT_REF to a reference EXR of scenes/render/$geometry.xml}"
        converge "mlt-$geometry" "${MLT_SCENE:-scenes/render/mlt-study.xml}" -D geometry="$geometry" \
            --reference "$MLT_REF" --config-file "${MLT_CONFIGS:-scenes/render/mlt-study.configs}" \
            --checkpoints "${MLT_CHECKPOINTS:-5,10,20,40,80}"
        figures "mlt-$geometry" error_vs_seconds_rel_mse.png error_vs_seconds_l1.png grid.png ;;
    all)
        for r in fluid-nmc fluid-cells fluid-dt fluid-params fluid-visual fluid-baselines; do report "$r"; done ;;
    *)
        echo "usage: $0 fluid-nmc|fluid-cells|fluid-dt|fluid-params|fluid-visual|fluid-baselines|mlt|all" >&2
        exit 2 ;;
    esac
}

report "${1:-}"
