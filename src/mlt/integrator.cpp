// pssmlt / drmlt: Metropolis light transport over the primary sample space. See include/kelvin/mlt/integrator.h
// and docs/mlt.md.
#include <kelvin/core/colormap.h>
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/progress.h>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/integrator.h>
#include <kelvin/mlt/local.h>
#include <kelvin/mlt/path_derivatives.h>
#include <kelvin/render/film.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>

#include "mlt/multiplexed.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>

namespace kelvin {
namespace {

std::shared_ptr<SamplingIntegrator> make_path_sampler(const std::string& technique, long long max_depth,
                                                      long long min_depth, long long rr_depth, bool hide_emitters) {
    Properties p("integrator", technique);
    p.set_int("max_depth", max_depth);
    p.set_int("min_depth", min_depth);
    p.set_int("rr_depth", rr_depth);
    p.set_bool("hide_emitters", hide_emitters);
    auto obj = std::dynamic_pointer_cast<SamplingIntegrator>(Registry::instance().create(p));
    if (!obj) throw Error("internal error: integrator '" + technique + "' is not a path sampler");
    return obj;
}

std::shared_ptr<Mutation> make_mutation(const std::string& type, double sigma = -1) {
    Properties p("mutation", type);
    if (sigma > 0) p.set_float("sigma", sigma);
    return std::dynamic_pointer_cast<Mutation>(Registry::instance().create(p));
}

}  // namespace

long long auto_chain_count(double mutations, double mutations_per_chain) {
    const double c = std::ceil(mutations / mutations_per_chain);
    return (long long)std::clamp(c, double(MinAutoChains), double(MaxAutoChains));
}

MetropolisIntegrator::MetropolisIntegrator(const Properties& props, bool delayed_rejection)
    : m_delayed_rejection(delayed_rejection) {
    const std::string technique = props.get_choice("technique", {"path", "bdpt", "mmlt", "volpath"});
    const long long max_depth = props.get_int("max_depth", -1, 62);
    const long long rr_depth = props.get_int("rr_depth", 1, 1 << 20);
    const bool hide_emitters = props.get_bool("hide_emitters");
    if (max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
    m_mmlt = technique == "mmlt";
    m_hide_emitters = hide_emitters;
    m_technique_loc = props.location_of("technique");
    if (m_mmlt && max_depth < 0)
        props.error("max_depth", "technique=\"mmlt\" runs chains per path length and needs a finite max_depth");
    m_bootstrap_samples = props.get_int("bootstrap_samples", 1, 1LL << 40);
    m_chains = props.get_int("chains", -1, 1 << 24);
    if (m_chains == 0) props.error("chains", "must be -1 (chosen from the mutation budget) or at least 1");
    m_mutations_per_chain = props.get_float("mutations_per_chain", 1, 1e15);
    m_mutations_per_pixel = props.get_float("mutations_per_pixel", 1e-9, 1e12);
    m_direct_samples = props.get_int("direct_samples", -1, 1 << 24);
    if (m_direct_samples == 0)
        props.error("direct_samples", "must be -1 (the chains render direct light too) or at least 1");
    m_normalization = props.get_float("normalization", -1, Inf);
    if (!(m_normalization == -1 || m_normalization > 0))
        props.error("normalization", "must be -1 (bootstrap) or positive");
    m_waste_recycling = props.get_bool("waste_recycling");
    m_config.large_step_prob = props.get_float("large_step_prob", 0, 1);

    if (!delayed_rejection) {
        m_first = props.get_object_as<Mutation>("mutation");
        if (!m_first) m_first = make_mutation("kelemen");
        m_config.type = DrType::None;
    } else {
        const std::string type = props.get_choice("type", {"orbital", "mira", "green"});
        m_config.type = parse_dr_type(type);
        m_config.timid_after_large = props.get_bool("timid_after_large");
        m_config.mixture = props.get_bool("mixture");
        const double scale_second = props.get_float("scale_second", 1e-6, 1e6);
        m_first = props.get_object_as<Mutation>("first");
        if (!m_first) m_first = make_mutation(m_config.type == DrType::Orbital ? "kelemen_pair" : "kelemen");
        m_second = props.get_object_as<Mutation>("second");
        if (!m_second) {
            if (m_config.type == DrType::Orbital) {
                m_second = make_mutation("orbital");
            } else {
                const double sigma = scale_second * m_first->scale();
                if (!(sigma <= 0.125))
                    props.error("scale_second", fmt::format("gives a second-stage sigma of {} (> 1/8)", sigma));
                m_second = make_mutation("gaussian", sigma);
            }
        } else if (props.has("scale_second")) {
            props.error("scale_second",
                        "sizes the default second stage only; set the nested <mutation name=\"second\"> instead");
        }
    }
    m_config.first = m_first.get();
    m_config.second = m_second.get();
    if (m_mmlt) {
        // The state's strategy selector is a fixed pair: small steps keep (s, t), large steps redraw it.
        m_config.streams = SampleStreamCount;
        m_config.fixed_pairs = uint64_t(1) << StrategyPair;
    }
    // Local kernels (h2mc) need derivatives of the path contribution with respect to the primary samples, which the
    // path technique provides (mlt/path_derivatives.h); the bidirectional ones do not.
    {
        const bool local1 = m_first->has_local(), local2 = m_second && m_second->has_local();
        m_local = local1 || local2;
        // An adaptive local kernel (langevin) may ask for a warm-up of each chain from an independent start
        // (MarkovChain::warm_up): the stage's own kernel (or, for a mixture, its first component's).
        for (const Mutation* m : {m_first.get(), m_second.get()})
            if (m && m->has_local())
                if (const auto* a = dynamic_cast<const AdaptiveLocalKernel*>(m->local(0)))
                    m_warmup = std::max(m_warmup, a->warmup_steps());
        if (m_local && technique != "path")
            props.error(!delayed_rejection ? std::string("mutation") : std::string(local1 ? "first" : "second"),
                        "h2mc and langevin need derivatives of the path contribution, which technique '" + technique +
                            "' does not provide; use technique=\"path\"");
    }
    m_rr_depth = int(rr_depth);
    // One set of rules for the chain and the scene (chain.h, rule 3), reported against the parameter at fault.
    if (auto p = check(m_config)) {
        const std::string part = p->part;
        props.error(!delayed_rejection && part == "first" ? std::string("mutation") : part, p->why);
    }

    // With direct_samples > 0 the chains sample paths of 3 or more edges and direct light (emitters seen
    // directly, one-bounce paths) is rendered by plain path tracing.
    const bool split = m_direct_samples > 0;
    m_min_edges = split ? 3 : 1;
    m_max_edges = int(max_depth);
    if (m_mmlt && split && max_depth < 3)
        props.error("max_depth", "with direct_samples > 0 the chains render paths of 3 or more edges; max_depth " +
                                     std::to_string(max_depth) + " leaves them nothing (set direct_samples=-1)");
    // mmlt traces subpaths with the shared bidirectional core; the bdpt sampler stands for it in validate().
    m_technique = make_path_sampler(m_mmlt ? "bdpt" : technique, max_depth, m_min_edges, rr_depth, hide_emitters);
    if (split)
        // (volpath's own direct pass: a one-bounce path through a medium needs its free flights.)
        m_direct = make_path_sampler(technique == "volpath" ? "volpath" : "path",
                                     max_depth < 0 ? 2 : std::min<long long>(2, max_depth), 1, rr_depth, hide_emitters);
}

MetropolisIntegrator::~MetropolisIntegrator() = default;

std::string MetropolisIntegrator::description() const {
    auto name = [](const Object* o) { return o && !o->plugin_name().empty() ? o->plugin_name() : std::string("?"); };
    const std::string technique = m_mmlt ? "mmlt" : name(m_technique.get());
    if (!m_delayed_rejection) return fmt::format("{} ({}, {})", plugin_name(), name(m_first.get()), technique);
    const char* type = m_config.type == DrType::Orbital ? "orbital"
                       : m_config.type == DrType::Mira  ? "Tierney–Mira"
                                                        : "Green–Mira";
    return fmt::format("{} ({}, {} {} {}, {})", plugin_name(), type, name(m_first.get()),
                       m_config.mixture ? "mixed with" : "then", name(m_second.get()), technique);
}

MltStatistics MetropolisIntegrator::statistics() const {
    std::lock_guard lock(m_stats_mutex);
    return m_stats;
}

// One render(): its steps are the methods of this class, called in order by run(), and the state they share is
// its members.
//
//   direct_pass()     direct illumination by plain Monte Carlo (direct_samples > 0)
//   bootstrap()       b = E[pi] over independent uniform states (per path length for mmlt)
//   allocate_chains() chains per path length, in proportion to each length's share of b
//   start_chains()    each chain starts at a bootstrap state resampled in proportion to pi
//   run_chains()      the progressive loop of mutations (run_passes), splatting into a fixed-point image
//   gather()          the chains' statistics, summed over ranks
//   report()          statistics into ctx.stats, the stage map
//
// Distributed (core/distributed.h): bootstrap blocks and chains are work units owned round-robin; the bootstrap
// values are shared (each written by one rank: an exact sum), the fixed-point splats and counters are integer sums,
// so rank 0's image is bit-identical to one process's.
class MetropolisIntegrator::Render {
public:
    Render(MetropolisIntegrator& mlt, const Scene& scene, RunContext& ctx)
        : I(mlt),
          scene(scene),
          ctx(ctx),
          comm(communicator_of(ctx)),
          sensor(*scene.sensor()),
          w(sensor.film().width()),
          h(sensor.film().height()),
          filter(sensor.film().filter()),
          // bdpt and mmlt: camera, light and connection streams interleaved pair by pair (pss.h).
          streams(mlt.m_mmlt ? SampleStreamCount : mlt.m_technique->sample_streams()),
          dom{Vec2d(-filter.radius()), Vec2d(w + 2 * filter.radius(), h + 2 * filter.radius()),
              (w + 2 * filter.radius()) * (h + 2 * filter.radius())},
          multiplexed(scene, dom),
          image(w, h, &filter),
          boot_seed(hash_combine(ctx.seed, 0x626f6f74)),
          chain_seed(hash_combine(ctx.seed, 0x6d6c7463)),
          pss_seed(hash_combine(ctx.seed, 0x70737321)),
          nboot(std::size_t(mlt.m_bootstrap_samples)) {
        // The chain count: given, or chosen from the mutation budget (docs/mlt.md, "How many chains").
        const double budget_mpp = ctx.spp > 0 ? double(ctx.spp) : I.m_mutations_per_pixel;
        n_chains =
            I.m_chains > 0 ? I.m_chains : auto_chain_count(budget_mpp * double(w) * double(h), I.m_mutations_per_chain);
        // Depths: one (edges -1: every length) for path and bdpt; one per path length for mmlt.
        if (I.m_mmlt) {
            for (int k = I.m_min_edges; k <= I.m_max_edges; ++k)
                if (!(I.m_hide_emitters && k == 1)) depth_edges.push_back(k);
        } else {
            depth_edges.push_back(-1);
        }
        D = depth_edges.size();
        max_vertices = I.m_mmlt ? I.m_max_edges + 1 : 0;
    }

    RunResult run() {
        if (!direct_pass() || !bootstrap()) return interrupted_result();
        allocate_chains();
        start_chains();
        const PassLoopResult loop = run_chains();
        gather();
        RunResult result;
        result.image = develop();
        result.interrupted = loop.interrupted;
        result.seconds = total.seconds();
        result.work = st.mutations_per_pixel;
        result.work_unit = "mutations/px";
        report(result);
        return result;
    }

private:
    struct Chain {
        std::unique_ptr<MarkovChain> mc;  // null on ranks that do not own the chain
        std::unique_ptr<PrimarySampleSpace> pss;
        Contributions f[4];  // indexed by Slot: x (current state), y, z, y*
        uint64_t steps_done = 0;
        std::size_t depth = 0;
        int edges = -1;
        double scale = 1;  // splat weight: b_k C / (b n_k) for mmlt, 1 otherwise
        std::unique_ptr<LightSubpaths> light;
        SubpathRays rays;
        std::vector<uint64_t> small, small_acc, att2, acc2;  // per strategy s (mmlt)
        uint64_t strategy_changes = 0;                       // by small steps (mmlt; must stay 0)
    };

    // F(x) and pi(x) of the state `pss` is bound to: a path or bdpt sample from a camera ray.
    double evaluate_camera(PrimarySampleSpace& pss, Contributions& out, SampleCounters& c) const {
        out.clear();
        const Vec2d film = dom.origin + pss.next_2d() * dom.extent;
        const Ray ray = sensor.sample_ray(film, pss.next_2d());
        c.splats = &out;
        Color3 L = I.m_technique->sample(scene, pss, ray, c);
        if (!sanitize(L)) ++c.invalid;
        out.splat(film, L * dom.area);
        out.film = film;
        for (const auto& it : out.items) out.pi += luminance(it.v);
        ++c.samples;
        return out.pi;
    }

    // Evaluates bootstrap state i (of depth i / nboot) into `f`, reading `x`.
    double evaluate_boot(std::size_t i, std::vector<double>& x, Contributions& f, SampleCounters& c, LightSubpaths* L,
                         SubpathRays& rays) const {
        PrimarySampleSpace pss(boot_seed, i, streams);
        x.clear();
        pss.bind(x);
        if (!I.m_mmlt) return evaluate_camera(pss, f, c);
        return multiplexed.evaluate(pss, f, c, depth_edges[i / nboot], *L, 0, false, rays);
    }

    // The target of chain `ch` (the light subpath of z is x's when the second stage does not move the light
    // stream, or, in a mixture, when y comes from the second kernel).
    double chain_eval(Chain& ch, CoordinateSource& src, Slot slot, SampleCounters& cnt) const {
        ch.pss->bind(src);
        if (!I.m_mmlt) return evaluate_camera(*ch.pss, ch.f[int(slot)], cnt);
        const bool second = slot == Slot::Z || (slot == Slot::Y && ch.mc->proposing_with_second());
        const bool light_fixed = !(second_stage_streams(ch.f[0].s, ch.edges) & (1u << int(SampleStream::Light)));
        return multiplexed.evaluate(*ch.pss, ch.f[int(slot)], cnt, ch.edges, *ch.light, int(slot),
                                    second && light_fixed, ch.rays);
    }

    RunResult interrupted_result() {
        RunResult out;
        out.interrupted = true;
        out.image = direct.empty() ? Bitmap(w, h) : std::move(direct);
        return out;
    }

    // 1. Direct illumination by plain Monte Carlo (direct_samples > 0). False if interrupted.
    bool direct_pass() {
        if (!I.m_direct) return true;
        Timer t;
        RunContext dctx;
        dctx.seed = ctx.seed;
        dctx.spp = I.m_direct_samples;
        dctx.quiet = ctx.quiet;
        dctx.progress_label = "Direct light";
        dctx.on_progress = ctx.on_progress;
        dctx.progress_nested = true;
        dctx.cancel = ctx.cancel;
        dctx.comm = ctx.comm;
        RunResult r = I.m_direct->render(scene, dctx);
        direct = std::move(r.image);
        for (const auto& c : dctx.stats.counters())
            ctx.stats.add(fmt::format("mlt.direct.{}", c.name.substr(c.name.find('.') + 1)), c.value, c.unit);
        st.seconds_direct = t.seconds();
        return !r.interrupted;
    }

    // 2. Bootstrap: b = E[pi] over independent uniform states (per path length for mmlt: bootstrap_samples each);
    // chains start from states resampled prop. to pi. False if interrupted.
    bool bootstrap() {
        Timer t;
        boot_pi.assign(nboot * D, 0.0);
        b_depth.assign(D, 0.0);
        nonzero_depth.assign(D, 0);
        constexpr std::size_t Block = 4096;
        const std::size_t total_boot = nboot * D, blocks = (total_boot + Block - 1) / Block;
        std::vector<SampleCounters> bc(blocks);
        std::vector<SubpathRays> brays(blocks);
        ProgressReporter progress(ctx, "Bootstrap", double(total_boot), "paths", /*time_limit=*/0, /*nested=*/true);
        parallel_for_owned_units(comm, blocks, [&](std::size_t b) {
            std::vector<double> x;
            Contributions f;
            std::unique_ptr<LightSubpaths> L = I.m_mmlt ? std::make_unique<LightSubpaths>(max_vertices) : nullptr;
            for (std::size_t i = b * Block; i < std::min(total_boot, (b + 1) * Block); ++i) {
                if ((i & 255) == 0 && ctx.cancel.stop_requested()) return;
                boot_pi[i] = evaluate_boot(i, x, f, bc[b], L.get(), brays[b]);
            }
            // (A distributed bootstrap reports rank 0's share, scaled to the whole.)
            progress.update(double(std::min(total_boot, (b + 1) * Block) - b * Block) * double(comm.size()));
        });
        progress.finish();
        allreduce_sum(comm, boot_pi);
        for (std::size_t d = 0; d < D; ++d) {
            double sum = 0;
            for (std::size_t i = d * nboot; i < (d + 1) * nboot; ++i) {
                sum += boot_pi[i];
                nonzero_depth[d] += boot_pi[i] > 0;
            }
            b_depth[d] = sum / double(nboot);
            st.bootstrap_nonzero += nonzero_depth[d];
        }
        for (const auto& c : bc) st.invalid_contributions += c.invalid;
        st.bootstrap_samples = nboot * D;
        double b = 0;
        for (double bd : b_depth) b += bd;
        // A given normalisation fixes the total; the bootstrap still splits it over path lengths (mmlt).
        if (I.m_normalization > 0) {
            for (double& bd : b_depth) bd = b > 0 ? bd * I.m_normalization / b : I.m_normalization / double(D);
            b = I.m_normalization;
        }
        st.normalization = b;
        st.seconds_bootstrap = t.seconds();
        if (any_rank(comm, ctx.cancel.stop_requested())) return false;
        if (st.bootstrap_nonzero == 0)
            log_warn(
                "{}: none of the {} bootstrap paths carries light; the Metropolis part of the image is black "
                "(raise bootstrap_samples if light paths are rare)",
                I.to_string(), nboot * D);
        return true;
    }

    // 3. Chains per depth: every depth whose bootstrap found light gets one, the rest in proportion to b_k (the
    // share of the image's luminance it carries; largest remainders), so a depth's share of the mutations is
    // about b_k / b, as in pbrt's MMLT, but never zero. Depth k's splats are weighted b_k C / (b n_k): each depth
    // has its own normalisation, whatever its share.
    void allocate_chains() {
        chains_of.assign(D, 0);
        std::size_t lit = 0;
        for (std::size_t d = 0; d < D; ++d) lit += nonzero_depth[d] > 0;
        if (lit > 0 && n_chains < (long long)lit) n_chains = (long long)lit;
        double b_lit = 0;
        for (std::size_t d = 0; d < D; ++d)
            if (nonzero_depth[d] > 0) b_lit += b_depth[d];
        const long long spare = n_chains - (long long)lit;
        long long given = 0;
        std::vector<std::pair<double, std::size_t>> rem;
        for (std::size_t d = 0; d < D; ++d) {
            if (nonzero_depth[d] == 0) continue;
            const double share = b_lit > 0 ? double(spare) * b_depth[d] / b_lit : 0.0;
            chains_of[d] = 1 + (long long)std::floor(share);
            given += chains_of[d];
            rem.emplace_back(share - std::floor(share), d);
        }
        std::stable_sort(rem.begin(), rem.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
        for (std::size_t r = 0; given < n_chains && r < rem.size(); ++r, ++given) ++chains_of[rem[r].second];
        st.chains = uint64_t(n_chains);
        counters.assign(static_cast<std::size_t>(n_chains), SampleCounters{});
        chains = std::vector<Chain>(st.bootstrap_nonzero > 0 ? std::size_t(n_chains) : 0);
        if (I.m_delayed_rejection) {
            stage_counts = std::vector<std::atomic<uint32_t>>(std::size_t(w) * std::size_t(h) * 2);
            for (auto& c : stage_counts) c.store(0, std::memory_order_relaxed);
        }
    }

    // 4. Systematic resampling of each depth's bootstrap states prop. to pi: chain c of the depth starts at the
    // state whose cumulative weight interval holds (c + u0) / C_k. Exact stationary start up to b.
    void start_chains() {
        if (chains.empty()) return;
        Random r(hash_combine(ctx.seed, 0x72657361), 0);
        const double u0 = r.next_double();
        std::vector<std::size_t> start(chains.size());
        std::size_t c = 0;
        for (std::size_t d = 0; d < D; ++d) {
            const std::size_t first = d * nboot, last = (d + 1) * nboot;
            double sum = 0;
            for (std::size_t i = first; i < last; ++i) sum += boot_pi[i];
            double acc = 0;
            std::size_t i = first;
            const long long nd = I.m_mmlt ? chains_of[d] : n_chains;
            for (long long j = 0; j < nd; ++j, ++c) {
                const double target = (double(j) + u0) / double(nd) * sum;
                while (i + 1 < last && (acc + boot_pi[i] <= target || boot_pi[i] == 0)) acc += boot_pi[i++];
                start[c] = i;
                chains[c].depth = d;
                chains[c].edges = depth_edges[d];
                if (I.m_mmlt) {
                    chains[c].scale = b_depth[d] * double(n_chains) / (st.normalization * double(nd));
                    const std::size_t ns = std::size_t(strategy_count(depth_edges[d]));
                    chains[c].small.assign(ns, 0);
                    chains[c].small_acc.assign(ns, 0);
                    chains[c].att2.assign(ns, 0);
                    chains[c].acc2.assign(ns, 0);
                }
            }
        }
        // Local kernels (h2mc): the chains ask the path technique's differentiable evaluation for derivatives; a path
        // it cannot differentiate (an unsupported plugin, a mismatch, a discontinuity) gives the kernel's isotropic
        // fallback, counted.
        if (I.m_local) {
            PathDerivativeOptions o;
            o.max_depth = I.m_max_edges;
            o.min_depth = I.m_min_edges;
            o.rr_depth = I.m_rr_depth;
            o.hide_emitters = I.m_hide_emitters;
            o.film_origin = dom.origin;
            o.film_extent = dom.extent;
            o.film_area = dom.area;
            I.m_derivatives = std::make_unique<PathDerivatives>(scene, o);
        }
        for (auto& n : derivative_status) n.store(0, std::memory_order_relaxed);
        // Warm-up starts (adaptive local kernels, MarkovChain::warm_up): per chain an independent draw from the
        // bootstrap states in proportion to pi, so that the adaptation a chain learns is independent of its own start
        // given the bootstrap (only without mmlt, which local kernels refuse).
        std::vector<double> boot_cdf;
        if (I.m_warmup > 0) {
            boot_cdf.resize(nboot);
            double acc = 0;
            for (std::size_t i = 0; i < nboot; ++i) boot_cdf[i] = acc += boot_pi[i];
        }
        parallel_for_owned_units(comm, chains.size(), [&](std::size_t c) {
            Chain& ch = chains[c];
            std::vector<double> x;
            Contributions scratch;
            SubpathRays ignored;
            if (I.m_mmlt) ch.light = std::make_unique<LightSubpaths>(max_vertices);
            if (!(evaluate_boot(start[c], x, scratch, counters[c], ch.light.get(), ignored) > 0))
                throw RuntimeError("internal error: a bootstrap state did not reproduce its value");
            ch.mc = std::make_unique<MarkovChain>(I.m_config, chain_seed, c,
                                                  /*stage_timing=*/I.m_delayed_rejection || I.m_local);
            if (I.m_derivatives) {
                const PathDerivatives* PD = I.m_derivatives.get();
                auto* status = derivative_status.data();
                ch.mc->set_derivatives([PD, status](const DerivativeQuery& q) {
                    const PathDerivativeStatus s =
                        PD->evaluate(q.coords, q.block, q.length, q.n, q.value, nullptr, q.grad, q.hess);
                    status[int(s)].fetch_add(1, std::memory_order_relaxed);
                    return s == PathDerivativeStatus::Ok;
                });
            }
            ch.pss = std::make_unique<PrimarySampleSpace>(pss_seed, c, streams);
            const MarkovChain::Target target = [&](CoordinateSource& src, Slot slot) {
                return chain_eval(ch, src, slot, counters[c]);
            };
            if (I.m_warmup > 0) {
                Random rw(hash_combine(ctx.seed, 0x7761726d), c);
                const double u = rw.next_double() * boot_cdf.back();
                std::size_t i = std::size_t(std::upper_bound(boot_cdf.begin(), boot_cdf.end(), u) - boot_cdf.begin());
                i = std::min(i, nboot - 1);
                while (i > 0 && boot_pi[i] == 0) --i;  // u on a zero-weight state's boundary
                std::vector<double> xw;
                if (!(evaluate_boot(i, xw, scratch, counters[c], nullptr, ignored) > 0))
                    throw RuntimeError("internal error: a warm-up state did not reproduce its value");
                ch.mc->warm_up(target, xw, I.m_warmup);
            }
            if (!(ch.mc->start(target, x) > 0))
                throw RuntimeError("internal error: a chain's first state has no value");
        });
        boot_pi = {};
    }

    void splat_state(const Contributions& f, double weight) {
        if (!(weight > 0) || !(f.pi > 0)) return;
        const double s = weight / f.pi;
        for (const auto& it : f.items) image.splat(it.film, it.v * s);
    }
    void count_stage(const Contributions& f, int stage) {
        const Vec2d film = f.film;
        if (!(film.x >= 0 && film.y >= 0 && film.x < w && film.y < h)) return;
        stage_counts[(std::size_t(film.y) * std::size_t(w) + std::size_t(film.x)) * 2 + std::size_t(stage - 1)]
            .fetch_add(1, std::memory_order_relaxed);
    }

    // Steps of chain c once `units` mutations per pixel are done in total: the work of a unit is dealt to the chains
    // round robin (chain_steps), a rule that depends on `units` only, so the result never depends on how passes are
    // sized, and no pass gives a chain a negative share.
    uint64_t steps_until(long long units, std::size_t c) const {
        const unsigned __int128 all = (unsigned __int128)(units) * (unsigned __int128)(uint64_t(w) * uint64_t(h));
        return chain_steps(all, c, chains.size());
    }

    // One slice of a pass: each chain of [begin, end) this rank owns makes its share of `n` mutations per pixel. The
    // chains splat into a fixed-point image (integer sums: order-independent), so slicing never changes the image.
    void pass(long long first, long long n, std::size_t begin, std::size_t end) {
        parallel_for_owned_units(comm, begin, end, [&](std::size_t c) {
            Chain& ch = chains[c];
            SampleCounters& cnt = counters[c];
            const uint64_t todo = steps_until(first + n, c) - steps_until(first, c);
            // One std::function per pass: built per step, it would allocate (the closure exceeds its small buffer).
            const MarkovChain::Target target = [&](CoordinateSource& src, Slot slot) {
                return chain_eval(ch, src, slot, cnt);
            };
            for (uint64_t k = 0; k < todo; ++k) {
                if (ctx.cancel.stop_requested()) return;  // every step: a chain started after a stop makes none
                const int s_x = ch.f[0].s;
                if (I.m_mmlt) ch.mc->set_second_stage_streams(second_stage_streams(s_x, ch.edges));
                const StepOutcome o = ch.mc->step(target);
                if (I.m_waste_recycling) {
                    splat_state(ch.f[0], o.w_x * ch.scale);
                    splat_state(ch.f[1], o.w_y * ch.scale);
                    splat_state(ch.f[2], o.w_z * ch.scale);  // y* (f[3]) is never splatted
                }
                if (I.m_mmlt && s_x >= 0) {
                    const std::size_t si = std::size_t(s_x);
                    if (!o.large) {
                        ++ch.small[si];
                        ch.small_acc[si] += o.accepted == 1;
                    }
                    if (o.second_stage) {
                        ++ch.att2[si];
                        ch.acc2[si] += o.accepted == 2;
                    }
                }
                if (o.accepted > 0) {
                    std::swap(ch.f[0], ch.f[o.accepted]);
                    if (ch.light) ch.light->accept(o.accepted);
                    if (I.m_mmlt && !o.large && ch.f[0].s != s_x) ++ch.strategy_changes;
                    if (!stage_counts.empty()) count_stage(ch.f[0], o.accepted);
                }
                if (!I.m_waste_recycling) splat_state(ch.f[0], ch.scale);
                ++ch.steps_done;
                steps_total.fetch_add(1, std::memory_order_relaxed);
            }
        });
    }

    // The image so far: the direct pass plus the chains' splats, and for drmlt the stage channels (collective in a
    // distributed run).
    Bitmap develop() const {
        Bitmap img = direct.empty() ? Bitmap(w, h) : direct;
        uint64_t n = steps_total.load();
        if (comm.distributed()) comm.allreduce(&n, 1, ReduceOp::Sum);
        if (n > 0) {
            Bitmap m = image.develop(st.normalization / double(n), comm);
            for (std::size_t i = 0; i < img.size(); ++i) img.data()[i] += m.data()[i];
        }
        if (I.m_delayed_rejection) {
            std::vector<uint64_t> stages(stage_counts.size());
            for (std::size_t k = 0; k < stages.size(); ++k) stages[k] = stage_counts[k].load(std::memory_order_relaxed);
            allreduce_sum(comm, stages);
            const int r = img.add_channel("stages.R"), g = img.add_channel("stages.G");
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    const std::size_t k = (std::size_t(y) * std::size_t(w) + std::size_t(x)) * 2;
                    img.at(x, y, r) = float(stages[k]);
                    img.at(x, y, g) = float(stages[k + 1]);
                }
        }
        return img;
    }

    // 5. The chains' progressive loop. Equal-time runs and checkpoints charge the bootstrap and the direct pass.
    PassLoopResult run_chains() {
        Timer tc;
        const long long target = (long long)std::ceil(I.m_mutations_per_pixel);
        PassLoopResult loop;
        if (!chains.empty())
            loop = run_passes(
                ctx, target, "mutations/px", chains.size(),
                [&](long long first, long long n, std::size_t begin, std::size_t end) { pass(first, n, begin, end); },
                [&] { return develop(); }, total.seconds());
        st.seconds_chains = tc.seconds();
        return loop;
    }

    // 6. Statistics: this rank's chains (those it owns have a MarkovChain), then summed over ranks.
    void gather() {
        for (const Chain& ch : chains)
            if (ch.mc) st.chain += ch.mc->stats();
        if (comm.distributed()) {
            ChainStats sum;
            for (const ChainStats& cs : allgather_vector(comm, std::vector<ChainStats>{st.chain})) sum += cs;
            st.chain = sum;
        }
        if (I.m_mmlt) gather_depths();
        for (const auto& c : counters) st.invalid_contributions += c.invalid;
        st.splat_overflow = image.overflowed();
        derivative_counts.resize(derivative_status.size());
        for (std::size_t i = 0; i < derivative_counts.size(); ++i) derivative_counts[i] = derivative_status[i].load();
        if (comm.distributed()) {
            std::vector<uint64_t> v = {st.invalid_contributions, st.splat_overflow};
            v.insert(v.end(), derivative_counts.begin(), derivative_counts.end());
            allreduce_sum(comm, v);
            st.invalid_contributions = v[0], st.splat_overflow = v[1];
            std::copy(v.begin() + 2, v.end(), derivative_counts.begin());
        }
        st.mutations_per_pixel = double(st.chain.steps) / (double(w) * double(h));
    }

    // Per path length (mmlt): chains, mutations, acceptance per strategy, rays.
    void gather_depths() {
        st.depths.resize(D);
        for (std::size_t d = 0; d < D; ++d) {
            auto& ds = st.depths[d];
            ds.edges = depth_edges[d];
            ds.normalization = b_depth[d];
            const std::size_t ns = std::size_t(strategy_count(depth_edges[d]));
            ds.small_steps.assign(ns, 0);
            ds.small_accepted.assign(ns, 0);
            ds.stage2_attempted.assign(ns, 0);
            ds.stage2_accepted.assign(ns, 0);
        }
        for (const Chain& ch : chains) {
            auto& ds = st.depths[ch.depth];
            ++ds.chains;
            if (!ch.mc) continue;  // another rank's
            ds.steps += ch.steps_done;
            for (std::size_t k = 0; k < ch.small.size(); ++k) {
                ds.small_steps[k] += ch.small[k];
                ds.small_accepted[k] += ch.small_acc[k];
                ds.stage2_attempted[k] += ch.att2[k];
                ds.stage2_accepted[k] += ch.acc2[k];
            }
            st.rays_camera += ch.rays.camera;
            st.rays_light += ch.rays.light;
            st.rays_connection += ch.rays.connection;
            st.rays_light_stage2 += ch.rays.light_stage2;
            st.light_subpaths_reused += ch.rays.reused;
            st.mmlt_strategy_changes_small += ch.strategy_changes;
        }
        if (!comm.distributed()) return;
        // Every per-depth and per-strategy count, flattened, summed over ranks and put back.
        std::vector<uint64_t*> fields = {&st.rays_camera,           &st.rays_light,
                                         &st.rays_connection,       &st.rays_light_stage2,
                                         &st.light_subpaths_reused, &st.mmlt_strategy_changes_small};
        for (auto& ds : st.depths) {
            fields.push_back(&ds.steps);
            for (auto* v : {&ds.small_steps, &ds.small_accepted, &ds.stage2_attempted, &ds.stage2_accepted})
                for (auto& x : *v) fields.push_back(&x);
        }
        std::vector<uint64_t> flat(fields.size());
        for (std::size_t i = 0; i < fields.size(); ++i) flat[i] = *fields[i];
        allreduce_sum(comm, flat);
        for (std::size_t i = 0; i < fields.size(); ++i) *fields[i] = flat[i];
    }

    // 7. Statistics (printed by the CLI, readable through statistics()) and the stage map.
    void report(RunResult& result) {
        report_counters(ctx, counters, "mlt.path_evaluations");
        auto& S = ctx.stats;
        const ChainStats& cs = st.chain;
        S.set("mlt.normalization", st.normalization);
        S.set("mlt.bootstrap_nonzero_fraction",
              st.bootstrap_samples ? double(st.bootstrap_nonzero) / double(st.bootstrap_samples) : 0.0);
        S.add("mlt.mutations", double(cs.steps), "mutations");
        S.set("mlt.mutations_per_pixel", st.mutations_per_pixel);
        S.set("mlt.mutations_per_second", st.mutations_per_second());
        S.set("mlt.acceptance.stage1_small", st.stage1_acceptance());
        if (cs.evaluations > st.chains)
            S.set("mlt.coordinates_per_state", 2.0 * double(cs.pairs_realised) / double(cs.evaluations - st.chains));
        S.set("mlt.acceptance.large_step", st.large_step_acceptance());
        if (I.m_delayed_rejection && !I.m_config.mixture) {
            S.set("mlt.acceptance.stage2", st.stage2_acceptance());
            S.add("mlt.stage2_attempts", double(cs.stage2_attempted), "attempts");
            S.set("mlt.stage2_time_share", st.stage2_time_share());
            if (I.type() == DrType::Green) {
                S.add("mlt.ystar_evaluations", double(cs.ystar_evaluations), "paths");
                S.add("mlt.ystar_skipped", double(cs.ystar_skipped), "paths");
            }
        }
        if (I.m_local) {
            // Named after the kernel: mlt.langevin.* when a stage is a langevin mutation, mlt.h2mc.* otherwise.
            const bool lgv =
                I.m_first->plugin_name() == "langevin" || (I.m_second && I.m_second->plugin_name() == "langevin");
            const std::string k = lgv ? "mlt.langevin." : "mlt.h2mc.";
            S.add(k + "proposals", double(cs.local_proposals), "proposals");
            S.set(k + "acceptance", cs.local_proposals ? double(cs.local_accepted) / double(cs.local_proposals) : 0.0);
            S.add(k + "derivatives", double(cs.derivatives), "paths");
            S.add(k + "not_differentiable", double(cs.not_differentiable), "paths");
            S.add(k + "unsupported", double(derivative_counts[int(PathDerivativeStatus::Unsupported)]), "paths");
            S.add(k + "mismatch", double(derivative_counts[int(PathDerivativeStatus::Mismatch)]), "paths");
            S.add(k + "too_long", double(derivative_counts[int(PathDerivativeStatus::TooLong)]), "paths");
            S.add(k + "discontinuous", double(derivative_counts[int(PathDerivativeStatus::Discontinuous)]), "paths");
            if (!lgv) S.add(k + "small_hessian", double(cs.small_hessian), "paths");
            S.set(k + "seconds_derivatives", cs.seconds_derivatives);
            S.set(k + "seconds_gaussians", cs.seconds_gaussians);
        }
        if (I.m_config.mixture) {
            S.add("mlt.mixture_second", double(cs.mixture_second), "mutations");
            S.set("mlt.acceptance.mixture_second",
                  cs.mixture_second ? double(cs.mixture_second_accepted) / double(cs.mixture_second) : 0.0);
        }
        if (I.m_mmlt) report_depths();
        S.add_time("mlt.time.bootstrap", st.seconds_bootstrap);
        S.add_time("mlt.time.direct", st.seconds_direct);
        S.add_time("mlt.time.chains", st.seconds_chains);
        if (st.splat_overflow > 0) {
            S.add("mlt.splat_overflow", double(st.splat_overflow), "splats");
            log_warn("{}: {} splat(s) out of the accumulator's range were dropped", I.to_string(), st.splat_overflow);
        }
        if (I.m_delayed_rejection && !ctx.output.empty() && comm.root()) write_stage_map(result);
        std::lock_guard lock(I.m_stats_mutex);
        I.m_stats = st;
    }

    void report_depths() {
        auto& S = ctx.stats;
        auto rate = [](uint64_t a, uint64_t n) { return n ? double(a) / double(n) : 0.0; };
        const bool stage2 = I.m_delayed_rejection && !I.m_config.mixture;
        S.add("mlt.mmlt.rays.camera", double(st.rays_camera), "rays");
        S.add("mlt.mmlt.rays.light", double(st.rays_light), "rays");
        S.add("mlt.mmlt.rays.connection", double(st.rays_connection), "rays");
        if (stage2) {
            S.add("mlt.mmlt.rays.light_stage2", double(st.rays_light_stage2), "rays");
            S.add("mlt.mmlt.light_subpaths_reused", double(st.light_subpaths_reused), "paths");
        }
        for (const auto& ds : st.depths) {
            const std::string k = fmt::format("mlt.mmlt.depth{}", ds.edges);
            S.set(k + ".normalization", ds.normalization);
            S.set(k + ".chains", double(ds.chains));
            S.set(k + ".mutation_share", st.chain.steps ? double(ds.steps) / double(st.chain.steps) : 0.0);
            uint64_t sm = 0, sa = 0, a2 = 0, c2 = 0;
            for (std::size_t i = 0; i < ds.small_steps.size(); ++i) {
                sm += ds.small_steps[i], sa += ds.small_accepted[i];
                a2 += ds.stage2_attempted[i], c2 += ds.stage2_accepted[i];
                if (ds.small_steps[i] == 0) continue;
                const std::string ks = fmt::format("{}.s{}t{}", k, i, ds.edges + 1 - int(i));
                S.set(ks + ".acceptance.stage1_small", rate(ds.small_accepted[i], ds.small_steps[i]));
                if (stage2) S.set(ks + ".acceptance.stage2", rate(ds.stage2_accepted[i], ds.stage2_attempted[i]));
            }
            S.set(k + ".acceptance.stage1_small", rate(sa, sm));
            if (stage2) S.set(k + ".acceptance.stage2", rate(c2, a2));
        }
    }

    // The stage map as a heat map: G / (R + G + 0.01), second-stage share of the acceptances (Fig. 4.1).
    void write_stage_map(RunResult& result) const {
        Bitmap heat(w, h);
        const int r = result.image.channel_index("stages.R"), g = result.image.channel_index("stages.G");
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x) {
                const double R = result.image.at(x, y, r), G = result.image.at(x, y, g);
                const Color3 c = viridis(G / (R + G + 0.01));
                heat.set_rgb(x, y, Color3(srgb_to_linear(c.r), srgb_to_linear(c.g), srgb_to_linear(c.b)));
            }
        const auto path = ctx.output.parent_path() / (ctx.output.stem().string() + "_stages.png");
        write_image(path, heat);
        result.files_written.push_back(path);
    }

    MetropolisIntegrator& I;
    const Scene& scene;
    RunContext& ctx;
    Communicator& comm;
    const Sensor& sensor;
    const int w, h;
    const ReconstructionFilter& filter;
    const int streams;
    const FilmDomain dom;
    const MultiplexedTechnique multiplexed;
    Timer total;
    MltStatistics st;
    long long n_chains = 0;
    std::vector<int> depth_edges;
    std::size_t D = 0;
    int max_vertices = 0;

    Bitmap direct;
    FixedPointSplatImage image;
    const uint64_t boot_seed, chain_seed, pss_seed;
    const std::size_t nboot;
    std::vector<double> boot_pi, b_depth;
    std::vector<uint64_t> nonzero_depth;
    std::vector<long long> chains_of;
    std::vector<Chain> chains;
    std::vector<SampleCounters> counters;
    std::vector<std::atomic<uint32_t>> stage_counts;
    std::atomic<uint64_t> steps_total{0};
    // Outcomes of the path derivatives the local kernels asked for, by PathDerivativeStatus (statistics only).
    std::array<std::atomic<uint64_t>, PathDerivativeStatusCount> derivative_status{};
    std::vector<uint64_t> derivative_counts;
};

RunResult MetropolisIntegrator::render(const Scene& scene, RunContext& ctx) {
    const Sensor& sensor = *scene.sensor();
    if (m_mmlt && !sensor.supports_connections())
        throw InputError(m_technique_loc,
                         fmt::format("{}: parameter 'technique': mmlt connects light subpaths to the camera and needs "
                                     "a perspective or thinlens sensor, not {}; use technique=\"path\"",
                                     to_string(), sensor.to_string()));
    m_technique->validate(scene);
    return Render(*this, scene, ctx).run();
}

}  // namespace kelvin
