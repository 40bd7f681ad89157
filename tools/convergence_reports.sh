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
#   tools/convergence_reports.sh fluid-lamb-oseen # the four solvers on a viscous Lamb–Oseen vortex (open box)
#   tools/convergence_reports.sh fluid-obstacle   # the four solvers on a Lamb–Oseen vortex in a disk container
#   tools/convergence_reports.sh fluid-shear      # the four solvers on the shear layer against two 512^2 references
#   tools/convergence_reports.sh fluid-long       # long times: inviscid Taylor–Green to t = 20, the 3D ring to t = 2
#   tools/convergence_reports.sh fluid-leapfrog   # leapfrogging rings to t = 4: passes, merger, energy, impulse of
#                                                 #   the 3D solvers at equal wall time against the exact dynamics
#   tools/convergence_reports.sh fluid-leapfrog-twice  # rings that leapfrog twice (t = 12), the same protocol
#   tools/convergence_reports.sh mlt            # the MLT family at equal time (MLT_REF=reference.exr, MLT_GEOMETRY)
#   tools/convergence_reports.sh mlt-door       # the thesis' equal-time protocol on one scene (docs/studies/mlt.md):
#   tools/convergence_reports.sh mlt-caustic    #   reference, normalisation from it, PSSMLT/G's sigma matched to DR,
#   tools/convergence_reports.sh mlt-plates     #   10 runs of the six variants, median [IQR] tables and figures
#   tools/convergence_reports.sh mlt-pool
#   tools/convergence_reports.sh mlt-all        # the four
#   tools/convergence_reports.sh mmlt-door      # the multiplexed family (Fig. 4.11): MMLT / K, MMLT / X, DR
#   tools/convergence_reports.sh mmlt-aquarium  #   multiplexed-then-subpath, technique mmlt, MLT_MAX_DEPTH (8)
#   tools/convergence_reports.sh mlt-torus      # cheap then expensive (Fig. 4.12): DR Gaussian-then-H2MC, H2MC and
#   tools/convergence_reports.sh mlt-chess      #   PSSMLT/G (sigma 0.01, DR's first stage), Langevin alone and DR
#                                               #   Gaussian-then-Langevin (MLT_LANGEVIN=0: not these two), path
#                                               #   technique, MLT_MAX_DEPTH (8)
#   tools/convergence_reports.sh all            # the nine fluid reports
#
# Environment: KELVIN (default build/bin/kelvin), OUT (default /tmp/kelvin-convergence; studies there are
# resumed, FRESH=1 deletes them first), RUNS (independent runs, default 3; the mlt-* studies: 10), THREADS
# (default: all cores; the mlt-* studies: 2). The mlt-* studies also read MLT_RES (256), MLT_CHECKPOINTS (seconds,
# default 30,60,120,240,480), MLT_REF_SPP (the reference's spp, per scene), MLT_REF_INTEGRATOR (bdpt; path: see
# docs/studies/mlt.md on bdpt's light-tracing strategy), MLT_DIRECT_REF_SPP (1024),
# MLT_REF_THREADS (the references' threads, default THREADS), MLT_SETUP_ONLY (1: stop after the references and b),
# MLT_TECHNIQUE (per scene), MLT_DIRECT_SAMPLES (-1, the chains render everything; 16, the integrators' split),
# MLT_MIXTURE (1: the mixture baseline as a variant),
# MLT_VARIANTS (which of pssmlt-K pssmlt-G pssmlt-G-bold mixture dr-orbital dr-orbital-G dr-mira dr-green; by
# default all but pssmlt-G-bold, in that order), MLT_DR_SIGMA (the sigma of dr-orbital-G's first stage and of
# pssmlt-G-bold, 0.03),
# MLT_MATCH_SPP (mutations per pixel of each sigma-matching render, default 4), MLT_FIGURES (1: copy the figures
# into docs/img), MLT_IMAGES (the checkpoint images kept: all, the default, for tools/run_spread.py; first; none). Everything a study computes is kept in $OUT (references, normalisation, sigma) and reused.
set -euo pipefail
cd "$(dirname "$0")/.."

KELVIN=${KELVIN:-build/bin/kelvin}
OUT=${OUT:-/tmp/kelvin-convergence}
RUNS_SET=${RUNS:-}
THREADS_SET=${THREADS:-}
RUNS=${RUNS:-3}
THREADS=${THREADS:-0}
TG=scenes/fluid/taylor_green.xml
# The thesis-style Taylor–Green studies (fluid-nmc, -cells, -dt, -params, -visual, -baselines) run MCFluid with
# the backtrace of their documented tables, the thesis' (a fresh estimate at every RK4 stage): TG_BACKTRACE=auto
# runs the current default instead (docs/convergence.md, "The 2D backtrace").
TG_BT=(-D "backtrace=${TG_BACKTRACE:-estimates}")

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

mlt_study() {  # mlt_study GEOMETRY [mmlt|h2mc]: the thesis' equal-time protocol on scenes/render/geometry/GEOMETRY.xml
    # Without a family: the PSSMLT family (Figs. 4.9, 4.10). mmlt: the multiplexed family (Fig. 4.11): MMLT / K,
    # MMLT / X and DR multiplexed-then-subpath on technique=mmlt, max_depth MLT_MAX_DEPTH (8), the reference too.
    # h2mc: cheap then expensive (Fig. 4.12): DR Gaussian-then-H2MC (green, Gaussian 0.01 first, then the mixture of
    # H2MC and a Gaussian of 0.0025), H2MC (pssmlt), PSSMLT/G with DR's first stage (sigma 0.01), and unless
    # MLT_LANGEVIN=0 Langevin (pssmlt) and DR Gaussian-then-Langevin (drmlt-langevin), on the path
    # technique (the one H2MC differentiates) with max_depth MLT_MAX_DEPTH (8), the reference too.
    local g=$1 family=${2:-pss} technique ref_spp max_depth=-1
    case "$g" in  # per scene: the path sampler the chains drive and the reference's bdpt spp
    door) technique=path ref_spp=16384 ;;
    caustic) technique=bdpt ref_spp=16384 ;;
    plates) technique=path ref_spp=8192 ;;
    pool) technique=path ref_spp=32768 ;;
    aquarium) technique=bdpt ref_spp=16384 ;;
    torus | chess) technique=path ref_spp=16384 ;;
    esac
    # The chains render everything (direct_samples -1) on every scene: a direct pass of fixed spp does not improve
    # with the budget, and at 256 x 256 it was 82-86 % of every variant's error on the door after 120 s (16 spp),
    # so the study measured the pass, not the chains, as on the caustic and the pool at 64 x 64
    # (docs/studies/mlt.md); on the plates the hard transport is itself two-edge. MLT_DIRECT_SAMPLES=16 gives the
    # integrators' default split.
    local direct=${MLT_DIRECT_SAMPLES:--1}
    local report="mlt-$g"
    if [[ "$family" == mmlt ]]; then
        technique=mmlt max_depth=${MLT_MAX_DEPTH:-8} report="mmlt-$g"
    elif [[ "$family" == h2mc ]]; then
        max_depth=${MLT_MAX_DEPTH:-8}
    fi
    technique=${MLT_TECHNIQUE:-$technique}
    ref_spp=${MLT_REF_SPP:-$ref_spp}
    local res=${MLT_RES:-256} study=scenes/render/mlt-study.xml refscene=scenes/render/mlt-reference.xml
    local setup="$OUT/$report-setup" ref="$OUT/$report-$res-reference.exr"
    local wref="$OUT/$report-$res-reference-wide.exr" dref="$OUT/$report-$res-direct-wide.exr"
    [[ -n "$RUNS_SET" ]] || RUNS=10
    [[ -n "$THREADS_SET" ]] || THREADS=2
    mkdir -p "$setup"
    # 1. References (long; kept in $OUT and reused: delete them to render again). Seeds 1000+ (runs use 0-9).
    # They are rendered M pixels wider on every side (the field of view widened to match) so that they cover the
    # margin the chains' film domain adds (tools/reference_normalization.py --margin); the studies measure
    # errors against the inner res x res pixels.
    local m=4 fov wres wfov
    fov=$(sed -n 's/.*<default name="fov" value="\([^"]*\)".*/\1/p' "scenes/render/geometry/$g.xml")
    wres=$((res + 2 * m))
    wfov=$(/usr/bin/python3 -c "import math; print(repr(2 * math.degrees(math.atan(math.tan(math.radians($fov) / 2) * $wres / $res))))")
    local wide=(-D geometry="$g" -D res="$wres" -D fov="$wfov" -t "${MLT_REF_THREADS:-$THREADS}" -q)
    # The reference is the mean of two independent halves (ref_spp / 2 each, seeds 1000 and 1002), kept beside
    # it, so that tools/reference_floor.py can measure the error its own noise adds to every variant.
    local half h hspp=$(((ref_spp + 1) / 2))
    if [[ ! -f "$wref" ]]; then
        echo "== $report: ${MLT_REF_INTEGRATOR:-bdpt} reference, ${res}x$res + $m pixels on every side, 2 x $hspp spp -> $wref"
        for h in a b; do
            half="${wref%.exr}-$h.exr"
            [[ -f "$half" ]] && continue
            # Into a temporary name, kept only if the render completed: an interrupted kelvin still writes the
            # image so far (exit 130), which must not pass for a reference next time.
            "$KELVIN" "$refscene" "${wide[@]}" -D integrator="${MLT_REF_INTEGRATOR:-bdpt}" -D max_depth="$max_depth" \
                --spp "$hspp" --seed "$([[ $h == a ]] && echo 1000 || echo 1002)" -o "${half%.exr}.tmp.exr"
            mv "${half%.exr}.tmp.exr" "$half"
        done
        oiiotool "${wref%.exr}-a.exr" --ch R,G,B "${wref%.exr}-b.exr" --ch R,G,B --add --mulc 0.5 \
            -o "${wref%.exr}.tmp.exr"
        mv "${wref%.exr}.tmp.exr" "$wref"
    fi
    if [[ -f "${wref%.exr}-a.exr" && -f "${wref%.exr}-b.exr" ]]; then  # older studies have a single reference
        /usr/bin/python3 tools/reference_floor.py "${wref%.exr}-a.exr" "${wref%.exr}-b.exr" --margin "$m" \
            >"$setup/reference_floor.txt"
        cat "$setup/reference_floor.txt"
    else
        rm -f "$setup/reference_floor.txt"
    fi
    [[ -f "$ref" ]] || oiiotool "$wref" --ch R,G,B --cut "${res}x$res+$m+$m" -o "$ref"
    local bargs=("$wref" --margin "$m")
    if ((direct > 0)); then  # the chains render paths of 3+ edges only: subtract the direct-only integral
        if [[ ! -f "$dref" ]]; then
            echo "== $report: direct-only reference (path, max_depth 2), ${MLT_DIRECT_REF_SPP:-1024} spp -> $dref"
            "$KELVIN" "$refscene" "${wide[@]}" -D integrator=path -D max_depth=2 \
                --spp "${MLT_DIRECT_REF_SPP:-1024}" --seed 1001 -o "${dref%.exr}.tmp.exr"
            mv "${dref%.exr}.tmp.exr" "$dref"
        fi
        bargs+=(--direct "$dref")
    fi
    # 2. The normalisation b from the reference (thesis Sec. 4.3.3), given to every variant.
    local b
    b=$(/usr/bin/python3 tools/reference_normalization.py "${bargs[@]}" -v 2>"$setup/normalization.log")
    cat "$setup/normalization.log"
    echo "normalization = $b" >"$setup/normalization.txt"
    local common=(-D geometry="$g" -D res="$res" -D technique="$technique" -D direct_samples="$direct" -D normalization="$b")
    if [[ "$family" == mmlt ]]; then
        common+=(-D max_depth="$max_depth")
        {
            echo "# $report: generated by tools/convergence_reports.sh (multiplexed MLT, max_depth $max_depth)"
            echo "mmlt-K: variant=pssmlt-kelemen"
            echo "mmlt-X: variant=drmlt-orbital-mixture"
            echo "dr-mmlt: variant=drmlt-orbital"
            # DR multiplexed-then-subpath after a bold Gaussian first stage (the best variant at 64 x 64, docs/studies/mlt.md)
            echo "dr-mmlt-G: variant=drmlt-orbital-gaussian first_sigma=${MLT_DR_SIGMA:-0.03}"
        } >"$setup/configs"
    elif [[ "$family" == h2mc ]]; then
        common+=(-D max_depth="$max_depth")
        {
            echo "# $report: generated by tools/convergence_reports.sh (cheap then expensive, max_depth $max_depth)"
            echo "dr-h2mc: variant=drmlt-h2mc"
            echo "h2mc: variant=pssmlt-h2mc"
            echo "pssmlt-G: variant=pssmlt-gaussian sigma=0.01"
            # Langevin (preconditioned MALA) alone and as DR's second stage after the same Gaussian first stage.
            if [[ "${MLT_LANGEVIN:-1}" == 1 ]]; then
                echo "langevin: variant=pssmlt-langevin"
                echo "dr-langevin: variant=drmlt-langevin"
            fi
        } >"$setup/configs"
    else
        mlt_sigma_configs
    fi
    if [[ "${MLT_SETUP_ONLY:-0}" == 1 ]]; then  # references, normalisation and configurations only
        echo "== $report: set up in $setup (MLT_SETUP_ONLY)"
        return 0
    fi
    converge "$report" "$study" "${common[@]}" --reference "$ref" --config-file "$setup/configs" \
        --checkpoints "${MLT_CHECKPOINTS:-30,60,120,240,480}" --images "${MLT_IMAGES:-all}"
    cp "$setup/normalization.txt" "$setup/normalization.log" "$setup/configs" "$OUT/$report/"
    [[ -f "$setup/reference_floor.txt" ]] && cp "$setup/reference_floor.txt" "$OUT/$report/"
    [[ -f "$setup/sigma.txt" ]] && cp "$setup/sigma.txt" "$OUT/$report/"
    # 5. Medians and interquartile ranges (the thesis' statistics), and the protocol's table.
    /usr/bin/python3 tools/plot_convergence.py "$OUT/$report/convergence.csv" --center median --metrics rel_mse,l1 >/dev/null
    /usr/bin/python3 tools/mlt_study_table.py "$OUT/$report" >"$OUT/$report/plots/table.md"
    echo "== $report: $OUT/$report/plots/table.md"
    cat "$OUT/$report/plots/table.md"
    if [[ "${MLT_FIGURES:-1}" == 1 ]]; then
        for f in error_vs_seconds_rel_mse.png error_vs_seconds_l1.png error_vs_work_rel_mse.png grid.png; do
            cp "$OUT/$report/plots/$f" "docs/img/convergence_${report//-/_}_$f"
        done
    fi
}

mlt_sigma_configs() {  # (mlt_study's locals) the PSSMLT family's configurations, PSSMLT/G's sigma matched
    # 3. PSSMLT/G's sigma matched to DR orbital's first-stage acceptance (reused while the settings are the same).
    local sigma match=(scenes/render/mlt-study.xml "${common[@]}" --spp "${MLT_MATCH_SPP:-4}" -t "$THREADS")
    if [[ -f "$setup/sigma.txt" && "$(head -1 "$setup/sigma.txt")" == "# ${match[*]}" ]] &&
        grep -q "within_tolerance = True" "$setup/sigma.txt"; then
        sigma=$(sed -n 's/^sigma = //p' "$setup/sigma.txt")
    else
        sigma=$(KELVIN="$KELVIN" /usr/bin/python3 tools/match_gaussian_sigma.py "${match[@]}" --record "$setup/sigma.tmp")
        { echo "# ${match[*]}"; cat "$setup/sigma.tmp"; } >"$setup/sigma.txt"
        rm -f "$setup/sigma.tmp"
    fi
    echo "== $report: normalization $b, matched sigma $sigma"
    # 4. The study: every variant, RUNS runs each, equal-time checkpoints.
    # MLT_VARIANTS picks and orders them (default: all seven; the mixture only with MLT_MIXTURE=1).
    local v variants=${MLT_VARIANTS:-pssmlt-K pssmlt-G mixture dr-orbital dr-orbital-G dr-mira dr-green}
    {
        echo "# $report: generated by tools/convergence_reports.sh (sigma matched to drmlt-orbital, $setup/sigma.txt)"
        for v in $variants; do
            case "$v" in
            pssmlt-K) echo "pssmlt-K: variant=pssmlt-kelemen" ;;
            pssmlt-G) echo "pssmlt-G: variant=pssmlt-gaussian sigma=$sigma" ;;
            # the single-stage counterpart of dr-orbital-G: its first stage alone
            pssmlt-G-bold) echo "pssmlt-G-bold: variant=pssmlt-gaussian sigma=${MLT_DR_SIGMA:-0.03}" ;;
            mixture) if [[ "${MLT_MIXTURE:-1}" == 1 ]]; then echo "mixture: variant=mixture"; fi ;;
            dr-orbital) echo "dr-orbital: variant=drmlt-orbital" ;;
            # DR orbital after a bold Gaussian first stage (sigma ${MLT_DR_SIGMA:-0.03}; docs/studies/mlt.md)
            dr-orbital-G) echo "dr-orbital-G: variant=drmlt-orbital-gaussian first_sigma=${MLT_DR_SIGMA:-0.03}" ;;
            dr-mira) echo "dr-mira: variant=drmlt-mira" ;;
            dr-green) echo "dr-green: variant=drmlt-green" ;;
            *) echo "convergence_reports.sh: unknown MLT_VARIANTS entry '$v'" >&2 && return 2 ;;
            esac
        done
    } >"$setup/configs"
}

# leapfrog_study NAME SCENE END TIMES TITLE REFERENCE_ARGS BASELINES BASELINE_RUNS [EXTRA]: the 3D solvers on coaxial
# rings to t = END against the exact axisymmetric dynamics (build/bin/ring_reference with REFERENCE_ARGS, its cores
# found on the solvers' spacing): MCFluid at the scene's defaults with seeds 1..RUNS; BASELINES and EXTRA are lists of
# "label:name=value,..." runs by -D (BASELINES BASELINE_RUNS times each, EXTRA once, with solver=mcfluid unless the
# entry sets it). Runs already in $OUT/NAME are kept (FRESH=1: all again). Table (medians over runs; energy and
# impulse at TIMES) and the core-track figure: tools/fluid_leapfrog_table.py; the figure goes to
# docs/img/convergence_<NAME with _>_cores.png.
leapfrog_study() {
    local name=$1 scene=$2 end=$3 times=$4 title=$5 refargs=$6 baselines=$7 base_runs=$8 extra=${9:-}
    local d="$OUT/$name"
    [[ "${FRESH:-0}" == 1 ]] && rm -rf "$d"
    mkdir -p "$d"
    touch "$d/seconds.txt"
    leap_run() {  # leap_run NAME -D...: one run into $d/NAME (unless it is there), its wall seconds into seconds.txt
        local run=$1
        shift
        if [[ -f "$d/$run/diagnostics.csv" ]] && grep -q "^$run " "$d/seconds.txt"; then return; fi
        local t0 t1
        t0=$(date +%s.%N)
        "$KELVIN" "$scene" -D end="$end" -D every=0 -t "$THREADS" -q -o "$d/$run.exr" "$@"
        t1=$(date +%s.%N)
        sed -i "/^$run /d" "$d/seconds.txt"
        echo "$run $(/usr/bin/python3 -c "print($t1 - $t0)")" >>"$d/seconds.txt"
    }
    entry_run() {  # entry_run "label:name=value,..." RUN: one run of a list entry, seed RUN
        local defs=(-D solver=mcfluid) kv x
        IFS=, read -ra kv <<<"${1#*:}"
        for x in "${kv[@]}"; do defs+=(-D "$x"); done
        leap_run "${1%%:*}_r$2" "${defs[@]}" --seed "$2"
    }
    # shellcheck disable=SC2086
    [[ -f "$d/reference.csv" ]] ||
        "${RING_REFERENCE:-build/bin/ring_reference}" $refargs --circulation 1 --dt 0.05 --end "$end" \
            -o "$d/reference.csv"
    local r e
    for r in $(seq 1 "$RUNS"); do
        leap_run "mcfluid_r$r" -D solver=mcfluid --seed "$r"
        if ((r == 1)); then for e in $extra; do entry_run "$e" 1; done; fi
        if ((r <= base_runs)); then for e in $baselines; do entry_run "$e" "$r"; done; fi
    done
    local sigma
    sigma=$(sed -n 's/.*--core \([0-9.]*\).*/\1/p' <<<"$refargs")
    /usr/bin/python3 tools/fluid_leapfrog_table.py "$d" --sigma "$sigma" --times "$times" --title "$title" \
        --plot "$d/leapfrog_cores.png" | tee "$d/summary.md"
    [[ -f "$d/leapfrog_cores.png" ]] && cp "$d/leapfrog_cores.png" "docs/img/convergence_${name//-/_}_cores.png"
    return 0
}

report() {
    case "$1" in
    fluid-nmc)
        mapfile -t c < <(configs n_mc spp 16 64 256 1024)
        converge fluid-nmc "$TG" "${TG_BT[@]}" -D res=64 -D dt=0.05 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-nmc error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-cells)
        mapfile -t c < <(configs nx res 16 32 64 128)
        converge fluid-cells "$TG" "${TG_BT[@]}" -D spp=256 -D dt=0.05 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-cells error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-dt)
        mapfile -t c < <(configs dt dt 0.25 0.125 0.0625 0.03125 0.015625)
        converge fluid-dt "$TG" "${TG_BT[@]}" -D res=64 -D spp=256 -D end=1 "${c[@]}" --times 0.25,0.5,1
        figures fluid-dt error_vs_param_rmse.png error_vs_cost_rmse.png ;;
    fluid-params)
        converge fluid-params "$TG" "${TG_BT[@]}" -D res=64 -D spp=256 -D dt=0.05 -D end=2 --times 0.5,1,2 \
            --config "baseline:" --config "nearest:interpolation=nearest" --config "kernel IS:importance=kernel" \
            --config "uniform:importance=uniform" --config "dt 0.2:dt=0.2" --config "32^2 cells:res=32" \
            --config "n_mc 64:spp=64" --config "euler:advection=euler"
        figures fluid-params error_vs_seconds_rmse.png error_vs_seconds_max_abs.png ;;
    fluid-visual)
        # One degraded parameter at a time on a moving flow (a vortex dipole), against a fine reference run at
        # t = 2 (computed once, kept in $OUT): errors, and the fields side by side.
        local ps=scenes/fluid/parameter_study.xml ref="$OUT/fluid-visual-reference.exr"
        mkdir -p "$OUT"
        [[ -f "$ref" ]] || "$KELVIN" "$ps" "${TG_BT[@]}" -D res=128 -D spp=1024 -D dt=0.025 --seed 1000 -t "$THREADS" -q -o "$ref"
        converge fluid-visual "$ps" "${TG_BT[@]}" --reference "$ref" --times 2 \
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
        converge fluid-baselines "$TG" "${TG_BT[@]}" -D spp=256 -D dt=0.05 -D end=1 "${c[@]}" --times 0.5,1
        figures fluid-baselines error_vs_cost_rmse.png error_vs_param_rmse.png ;;
    fluid-lamb-oseen | fluid-obstacle)
        # Equal-error tables with an exact solution away from periodic boxes (issue 16, item 4): the four solvers at
        # 16^2, 32^2 and 64^2 on a Lamb–Oseen vortex, viscous in an open box (fluid-lamb-oseen; the grid solvers
        # close the box [-1.2, 1.2]^2 with free-slip walls, 8 core radii from the centre) or inviscid, centred in a disk
        # container (fluid-obstacle: every solver's curved wall, a streamline of the exact flow).
        # The errors are over the cells where the exact solution holds and away from the walls, whose free-slip
        # velocity jump the grid solvers' curl turns into a vortex sheet in the first cells: the box [-1, 1]^2 of
        # the open case, the disk of radius 0.8 inside the container of radius 0.9 (outside it the exact free-space
        # flow is not the container's).
        # fluid-obstacle: MCFluid at 4 gradient samples, the control variate's equal-error setting with the bilinear
        # transport (its 64^2 vorticity error matches the plain walks' at 32: docs/convergence.md; the plain walks
        # are -D cv=false -D strat=false), and at 16 (mcfluid-n16), where a less diffusive transport leaves the
        # velocity noise as the larger error.
        local scene=scenes/fluid/lamb_oseen.xml spp=128 region=(--window -1,-1,1,1)
        c=()
        if [[ "$1" == fluid-obstacle ]]; then
            scene=scenes/fluid/lamb_oseen_disk.xml spp=4 region=(--disk 0,0,0.8)
            for r in 16 32 64; do c+=(--config "mcfluid-n16 res=$r:solver=mcfluid,res=$r,spp=16"); done
            # The cached, filtered backtrace (not the default with walls) at 16 samples: one walk estimate per cell
            # and step, about mcfluid's time at 4 samples with a fresh estimate at every RK4 stage.
            for r in 16 32 64; do c+=(--config "mcfluid-cache res=$r:solver=mcfluid,res=$r,spp=16,backtrace=cache"); done
            # Walks at every query instead of the harmonic cache (the default before it).
            for r in 16 32 64; do c+=(--config "mcfluid-walks res=$r:solver=mcfluid,res=$r,hcache=false"); done
        else  # the thesis' backtrace (a fresh estimate at every RK4 stage) beside the default's filtered cache
            for r in 16 32 64; do c+=(--config "mcfluid-estimates res=$r:solver=mcfluid,res=$r,backtrace=estimates"); done
        fi
        for s in mcfluid vortex_particles stable_fluids flip; do
            for r in 16 32 64; do c+=(--config "$s res=$r:solver=$s,res=$r"); done
        done
        converge "$1" "$scene" -D spp=$spp -D dt=0.05 -D end=1 "${region[@]}" --field vorticity --field u \
            "${c[@]}" --times 0.5,1
        figures "$1" error_vs_cost_rmse.png error_vs_param_rmse.png ;;
    fluid-long)
        # Long times, where a method's dissipation shows: the inviscid Taylor–Green cells to t = 20 (steady: any change
        # is error) with every 2D solver at 64^2 (MCFluid with the cubic and the linear lookup), and the 3D vortex
        # ring to t = 2 (constant energy; the exact ring's speed from the axisymmetric reference of the tests) with
        # MCFluid and the grid baselines at 40^3. RUNS runs each, seeds 1..RUNS (the table gives medians and the
        # range); wall seconds per run.
        local d="$OUT/fluid-long"
        [[ "${FRESH:-0}" == 1 ]] && rm -rf "$d"
        mkdir -p "$d"
        : >"$d/seconds.txt"
        long_run() {  # long_run NAME SCENE -D...: one run into $d/NAME, its wall seconds into seconds.txt
            local name=$1 scene=$2
            shift 2
            local t0 t1
            t0=$(date +%s.%N)
            "$KELVIN" "$scene" -D every=0 -q -o "$d/$name.exr" "$@"
            t1=$(date +%s.%N)
            echo "$name $(python3 -c "print($t1 - $t0)")" >>"$d/seconds.txt"
        }
        for r in $(seq 1 "$RUNS"); do
            for s in mcfluid mcfluid-estimates mcfluid-linear vortex_particles stable_fluids flip; do
                local solver=${s%-*} extra=()
                # The thesis' backtrace (a fresh estimate at every RK4 stage) at n_mc 256, about the time of the
                # default's 1024 cached; with the bilinear lookup, the thesis' scheme.
                [[ "$s" == *-linear ]] && extra=(-D transport=linear -D backtrace=estimates -D spp=256)
                [[ "$s" == *-estimates ]] && extra=(-D backtrace=estimates -D spp=256)
                long_run "tg_${s}_r$r" scenes/fluid/taylor_green.xml -D solver=$solver -D end=20 --seed "$r" "${extra[@]}"
            done
            for s in mcfluid mcfluid-estimates mcfluid-linear stable_fluids flip; do
                local solver=${s%-*} extra=()
                # The thesis' backtrace (fresh estimates at every RK4 stage, no smoothing); with the trilinear
                # lookup as well, the thesis' scheme.
                [[ "$s" == *-linear ]] && extra=(-D transport=linear -D backtrace=estimates)
                [[ "$s" == *-estimates ]] && extra=(-D backtrace=estimates)
                long_run "ring_${s}_r$r" scenes/fluid/vortex_ring.xml -D solver=$solver -D end=2 --seed "$r" "${extra[@]}"
            done
            # At about MCFluid's wall time: the baselines on finer grids (Taylor–Green ~7-30 s, the ring ~2-3 s).
            for sr in stable_fluids:256 stable_fluids:512 flip:128 flip:256 vortex_particles:32; do
                long_run "tg_${sr%:*}-${sr#*:}_r$r" scenes/fluid/taylor_green.xml -D solver=${sr%:*} -D res=${sr#*:} \
                    -D end=20 --seed "$r"
            done
            for res in 56 64; do
                long_run "ring_stable_fluids-${res}_r$r" scenes/fluid/vortex_ring.xml -D solver=stable_fluids -D res=$res \
                    -D end=2 --seed "$r"
            done
        done
        python3 tools/fluid_long_table.py "$d" | tee "$d/summary.md" ;;
    fluid-leapfrog)
        # Leapfrogging rings (scenes/fluid/leapfrog.xml: R 1, Gamma 1, sigma 0.2, centres 0.6 apart, inviscid) to
        # t = 4, against the exact axisymmetric dynamics (build/bin/ring_reference, its cores found on the solvers'
        # spacing 5/48). MCFluid at its defaults (48^3, n_mc 128, dt 0.1) and with the thesis' backtrace (fresh
        # estimates at every RK4 stage, no smoothing: mcfluid-thesis) with seeds 1..RUNS; stable_fluids and flip
        # at 48^3 and on finer grids taking about MCFluid's wall time (LEAPFROG_FINE, default stable_fluids:80 and
        # flip:50: measured 11.7 and 12.2 s against MCFluid's 12.9 s on 2 idle cores), RUNS runs each. Runs already in
        # $OUT are kept (FRESH=1: all again). Table (medians over runs) and the core-track figure:
        # tools/fluid_leapfrog_table.py; the figure goes to docs/img/convergence_fluid_leapfrog_cores.png.
        local base="mcfluid-thesis:backtrace=estimates stable_fluids:solver=stable_fluids flip:solver=flip" sr
        for sr in ${LEAPFROG_FINE:-stable_fluids:80 flip:50}; do
            base+=" ${sr%:*}-${sr#*:}:solver=${sr%:*},res=${sr#*:}"
        done
        leapfrog_study fluid-leapfrog scenes/fluid/leapfrog.xml 4 "2,4" "R 1, sigma 0.2, 0.6 apart" \
            "--radius 1 --core 0.2 --offsets 0,0.6 --spacing 0.10416666666666667" "$base" "$RUNS" ;;
    fluid-leapfrog-twice)
        # Rings that leapfrog twice in the exact dynamics (scenes/fluid/leapfrog_twice.xml: R 1.5, sigma 0.2, centres
        # 1.1 apart, to t = 12), the same protocol. The grid baselines close the box with free-slip walls, which
        # 0.5 from the widest ring slow it (its speed 0.49 of the exact one's for stable fluids, 0.72 in a box 1.4x
        # wider), so they run in the wider box (half=3.4) at the scene's spacing (res 78) and stable fluids also on
        # a finer grid of about MCFluid's wall time (res 162); deterministic, once each. LEAPFROG_TWICE_EXTRA: MCFluid
        # variants (default: twice the samples; the thesis' scheme, without the scene's smoothed velocities; the 3D
        # solver's default smoothing instead of the scene's).
        leapfrog_study fluid-leapfrog-twice scenes/fluid/leapfrog_twice.xml 12 "4,8,12" "R 1.5, sigma 0.2, 1.1 apart" \
            "--radius 1.5 --core 0.2 --offsets 0,1.1 --spacing 0.08727272727272727" \
            "${LEAPFROG_TWICE_BASELINES:-stable_fluids:solver=stable_fluids,half=3.4,res=78 flip:solver=flip,half=3.4,res=78 stable_fluids-162:solver=stable_fluids,half=3.4,res=162}" \
            1 "${LEAPFROG_TWICE_EXTRA:-mcfluid-n1024:spp=1024 mcfluid-thesis:bt=estimates,sfilter=0 mcfluid-defaults:kernel=twicing,sfilter=0.75}" ;;
    fluid-shear)
        # The shear layer has no exact solution: two references at 512^2 and dt = 0.0125 (stable fluids and FLIP,
        # kept in $OUT), the four solvers at 32^2..128^2 against each, at t = 2 (before the roll-up saturates).
        mkdir -p "$OUT/fluid-shear-refs"
        for ref in stable_fluids flip; do
            [[ -f "$OUT/fluid-shear-refs/$ref.exr" ]] ||
                "$KELVIN" scenes/fluid/shear_layer.xml -D solver=$ref -D res=512 -D dt=0.0125 -D end=2 -D every=0 \
                    -q -o "$OUT/fluid-shear-refs/$ref.exr"
        done
        # MCFluid at its scene's n_mc (512: one estimate per cell and step, its backtrace reading the filtered cache)
        # and with the thesis' backtrace (a fresh estimate at every RK4 stage) at n_mc 128, about the same time.
        c=()
        for s in mcfluid mcfluid-estimates vortex_particles stable_fluids flip; do
            local extra=""
            [[ "$s" == mcfluid ]] && extra=",spp=512"
            [[ "$s" == mcfluid-estimates ]] && extra=",backtrace=estimates"
            for r in 32 64 128; do c+=(--config "$s res=$r:solver=${s%-estimates},res=$r$extra"); done
        done
        for ref in stable_fluids flip; do
            converge "fluid-shear-$ref" scenes/fluid/shear_layer.xml -D spp=128 -D dt=0.05 -D end=2 "${c[@]}" \
                --reference "$OUT/fluid-shear-refs/$ref.exr" --times 2
        done
        figures fluid-shear-stable_fluids error_vs_cost_rmse.png ;;
    mlt)
        # The MLT family at equal time on one of the project's hard scenes: scenes/render/mlt-study.xml picks the
        # variant (scenes/render/mlt-study.configs, one configuration each) and the geometry (MLT_GEOMETRY: door or
        # caustic). MLT_REF is a long reference render of the same geometry and resolution.
        # (Study directory mlt-custom-<geometry>: mlt-<geometry> is the protocol study below.)
        local geometry=${MLT_GEOMETRY:-door}
        : "${MLT_REF:?set MLT_REF to a reference EXR of scenes/render/$geometry.xml}"
        converge "mlt-custom-$geometry" "${MLT_SCENE:-scenes/render/mlt-study.xml}" -D geometry="$geometry" \
            --reference "$MLT_REF" --config-file "${MLT_CONFIGS:-scenes/render/mlt-study.configs}" \
            --checkpoints "${MLT_CHECKPOINTS:-5,10,20,40,80}"
        figures "mlt-custom-$geometry" error_vs_seconds_rel_mse.png error_vs_seconds_l1.png grid.png ;;
    mlt-door | mlt-caustic | mlt-plates | mlt-pool)
        mlt_study "${1#mlt-}" ;;
    mmlt-door | mmlt-aquarium)
        mlt_study "${1#mmlt-}" mmlt ;;
    mlt-torus | mlt-chess)
        mlt_study "${1#mlt-}" h2mc ;;
    mlt-all)
        for g in door caustic plates pool; do mlt_study "$g"; done ;;
    all)
        for r in fluid-nmc fluid-cells fluid-dt fluid-params fluid-visual fluid-baselines fluid-lamb-oseen \
            fluid-obstacle fluid-shear; do report "$r"; done ;;
    *)
        echo "usage: $0 fluid-nmc|fluid-cells|fluid-dt|fluid-params|fluid-visual|fluid-baselines|fluid-lamb-oseen|fluid-obstacle|fluid-shear|fluid-long|fluid-leapfrog|fluid-leapfrog-twice|mlt|mlt-door|mlt-caustic|mlt-plates|mlt-pool|mlt-all|mmlt-door|mmlt-aquarium|mlt-torus|mlt-chess|all" >&2
        exit 2 ;;
    esac
}

report "${1:-}"
