// pssmlt / drmlt: Metropolis light transport over the primary sample space. See include/kelvin/mlt/integrator.h
// and docs/mlt.md.
#include <kelvin/core/colormap.h>
#include <kelvin/core/error.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/registry.h>
#include <kelvin/mlt/integrator.h>
#include <kelvin/render/film.h>
#include <kelvin/render/pss.h>
#include <kelvin/render/scene.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>

namespace kelvin {
namespace {

/// The contribution list F(x) of one state: (film position, value) pairs. A SplatSink, so that a path sampler
/// that splats (bdpt) writes straight into it. Keeps its capacity: no allocation once warm.
struct Contributions final : SplatSink {
    struct Item {
        Vec2d film;
        Color3 v;
    };
    std::vector<Item> items;
    double pi = 0;  ///< target value: sum of luminances

    void splat(const Vec2d& film, const Color3& v) override {
        if (v != Color3(0.0)) items.push_back({film, v});
    }
    void clear() {
        items.clear();
        pi = 0;
    }
};

/// Where camera samples land: the image grown by the filter radius on every side (border pixels receive
/// samples from outside the image, as they do when the pixel loop importance-samples the filter).
struct FilmDomain {
    Vec2d origin{0.0}, extent{1.0};
    double area = 1;  ///< extent.x * extent.y: the camera contribution's factor (the inverse density of u)
};

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
    const std::string technique = props.get_choice("technique", {"path", "bdpt"});
    const long long max_depth = props.get_int("max_depth", -1, 62);
    const long long rr_depth = props.get_int("rr_depth", 1, 1 << 20);
    const bool hide_emitters = props.get_bool("hide_emitters");
    if (max_depth == 0) props.error("max_depth", "must be -1 (unbounded) or at least 1");
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
    // One set of rules for the chain and the scene (chain.h, rule 3), reported against the parameter at fault.
    if (auto p = check(m_config)) {
        const std::string part = p->part;
        props.error(!delayed_rejection && part == "first" ? std::string("mutation") : part, p->why);
    }

    // With direct_samples > 0 the chains sample paths of 3 or more edges and direct light (emitters seen
    // directly, one-bounce paths) is rendered by plain path tracing.
    const bool split = m_direct_samples > 0;
    m_technique = make_path_sampler(technique, max_depth, split ? 3 : 1, rr_depth, hide_emitters);
    if (split)
        m_direct = make_path_sampler("path", max_depth < 0 ? 2 : std::min<long long>(2, max_depth), 1, rr_depth,
                                     hide_emitters);
}

MetropolisIntegrator::~MetropolisIntegrator() = default;

MltStatistics MetropolisIntegrator::statistics() const {
    std::lock_guard lock(m_stats_mutex);
    return m_stats;
}

RunResult MetropolisIntegrator::render(const Scene& scene, RunContext& ctx) {
    Timer total;
    const Sensor& sensor = *scene.sensor();
    m_technique->validate(scene);
    const int w = sensor.film().width(), h = sensor.film().height();
    const ReconstructionFilter& filter = sensor.film().filter();
    const int streams = m_technique->sample_streams();  // bdpt: camera, light and connection streams interleaved
    FilmDomain dom;
    dom.origin = Vec2d(-filter.radius());
    dom.extent = Vec2d(w + 2 * filter.radius(), h + 2 * filter.radius());
    dom.area = dom.extent.x * dom.extent.y;
    MltStatistics st;
    // The chain count: given, or chosen from the mutation budget (docs/mlt.md, "How many chains").
    const double budget_mpp = ctx.spp > 0 ? double(ctx.spp) : m_mutations_per_pixel;
    const long long n_chains =
        m_chains > 0 ? m_chains : auto_chain_count(budget_mpp * double(w) * double(h), m_mutations_per_chain);
    st.chains = uint64_t(n_chains);

    // F(x) and pi(x) of the state `pss` is bound to.
    auto evaluate = [&](PrimarySampleSpace& pss, Contributions& out, SampleCounters& c) {
        out.clear();
        const Vec2d film = dom.origin + pss.next_2d() * dom.extent;
        const Ray ray = sensor.sample_ray(film, pss.next_2d());
        c.splats = &out;
        Color3 L = m_technique->sample(scene, pss, ray, c);
        if (!sanitize(L)) ++c.invalid;
        out.splat(film, L * dom.area);
        for (const auto& it : out.items) out.pi += luminance(it.v);
        ++c.samples;
        return out.pi;
    };

    // 1. Direct illumination by plain Monte Carlo (direct_samples > 0).
    Bitmap direct;
    if (m_direct) {
        Timer t;
        RunContext dctx;
        dctx.seed = ctx.seed;
        dctx.spp = m_direct_samples;
        dctx.quiet = true;
        RunResult r = m_direct->render(scene, dctx);
        direct = std::move(r.image);
        for (const auto& c : dctx.stats.counters())
            ctx.stats.add(fmt::format("mlt.direct.{}", c.name.substr(c.name.find('.') + 1)), c.value, c.unit);
        st.seconds_direct = t.seconds();
        if (r.interrupted) {
            RunResult out;
            out.interrupted = true;
            out.image = std::move(direct);
            return out;
        }
    }

    // 2. Bootstrap: b = E[pi] over independent uniform states; chains start from states resampled prop. to pi.
    const uint64_t boot_seed = hash_combine(ctx.seed, 0x626f6f74), chain_seed = hash_combine(ctx.seed, 0x6d6c7463),
                   pss_seed = hash_combine(ctx.seed, 0x70737321);
    const std::size_t nboot = std::size_t(m_bootstrap_samples);
    std::vector<double> boot_pi(nboot, 0.0);
    std::vector<SampleCounters> counters(static_cast<std::size_t>(n_chains));
    {
        Timer t;
        constexpr std::size_t Block = 4096;
        const std::size_t blocks = (nboot + Block - 1) / Block;
        std::vector<SampleCounters> bc(blocks);
        parallel_for_units(blocks, [&](std::size_t b) {
            std::vector<double> x;
            Contributions f;
            for (std::size_t i = b * Block; i < std::min(nboot, (b + 1) * Block); ++i) {
                if ((i & 255) == 0 && interrupt_requested()) return;
                PrimarySampleSpace pss(boot_seed, i, streams);
                x.clear();
                pss.bind(x);
                boot_pi[i] = evaluate(pss, f, bc[b]);
            }
        });
        double sum = 0;
        for (double p : boot_pi) {
            sum += p;
            st.bootstrap_nonzero += p > 0;
        }
        for (const auto& c : bc) st.invalid_contributions += c.invalid;
        st.bootstrap_samples = nboot;
        st.normalization = m_normalization > 0 ? m_normalization : sum / double(nboot);
        st.seconds_bootstrap = t.seconds();
        if (interrupt_requested()) {
            RunResult out;
            out.interrupted = true;
            out.image = direct.empty() ? Bitmap(w, h) : std::move(direct);
            return out;
        }
        if (st.bootstrap_nonzero == 0)
            log_warn(
                "{}: none of the {} bootstrap paths carries light; the Metropolis part of the image is black "
                "(raise bootstrap_samples if light paths are rare)",
                to_string(), nboot);
    }

    // 3. Chains.
    struct Chain {
        std::unique_ptr<MarkovChain> mc;
        std::unique_ptr<PrimarySampleSpace> pss;
        Contributions f[4];  // indexed by Slot: x (current state), y, z, y*
        uint64_t steps_done = 0;
    };
    std::vector<Chain> chains(st.bootstrap_nonzero > 0 ? std::size_t(n_chains) : 0);
    if (!chains.empty()) {
        // Systematic resampling of the bootstrap states prop. to pi: chain c starts at the state whose
        // cumulative weight interval holds (c + u0) / C. Exact stationary start up to the bootstrap's b.
        std::vector<std::size_t> start(chains.size());
        Random r(hash_combine(ctx.seed, 0x72657361), 0);
        const double u0 = r.next_double();
        double total = 0;
        for (double p : boot_pi) total += p;
        double acc = 0;
        std::size_t i = 0;
        for (std::size_t c = 0; c < chains.size(); ++c) {
            const double target = (double(c) + u0) / double(chains.size()) * total;
            while (i + 1 < nboot && (acc + boot_pi[i] <= target || boot_pi[i] == 0)) acc += boot_pi[i++];
            start[c] = i;
        }
        parallel_for_units(chains.size(), [&](std::size_t c) {
            Chain& ch = chains[c];
            std::vector<double> x;
            PrimarySampleSpace boot(boot_seed, start[c], streams);
            boot.bind(x);
            Contributions scratch;
            if (!(evaluate(boot, scratch, counters[c]) > 0))
                throw RuntimeError("internal error: a bootstrap state did not reproduce its value");
            ch.mc = std::make_unique<MarkovChain>(m_config, chain_seed, c, /*stage_timing=*/m_delayed_rejection);
            ch.pss = std::make_unique<PrimarySampleSpace>(pss_seed, c, streams);
            const MarkovChain::Target target = [&](CoordinateSource& src, Slot slot) {
                ch.pss->bind(src);
                return evaluate(*ch.pss, ch.f[int(slot)], counters[c]);
            };
            if (!(ch.mc->start(target, x) > 0))
                throw RuntimeError("internal error: a chain's first state has no value");
        });
    }
    boot_pi = {};

    FixedPointSplatImage image(w, h, &filter);
    std::vector<std::atomic<uint32_t>> stage_counts(m_delayed_rejection ? std::size_t(w) * std::size_t(h) * 2 : 0);
    for (auto& s : stage_counts) s.store(0, std::memory_order_relaxed);
    const double P = double(w) * double(h);
    std::atomic<uint64_t> steps_total{0};

    auto splat_state = [&](const Contributions& f, double weight) {
        if (!(weight > 0) || !(f.pi > 0)) return;
        const double s = weight / f.pi;
        for (const auto& it : f.items) image.splat(it.film, it.v * s);
    };
    auto count_stage = [&](const std::vector<double>& state, int stage) {
        const Vec2d film = dom.origin + Vec2d(state[0], state[1]) * dom.extent;
        if (!(film.x >= 0 && film.y >= 0 && film.x < w && film.y < h)) return;
        stage_counts[(std::size_t(film.y) * std::size_t(w) + std::size_t(film.x)) * 2 + std::size_t(stage - 1)]
            .fetch_add(1, std::memory_order_relaxed);
    };

    // Steps of chain c once `units` mutations per pixel are done in total: the work of a unit is split over the
    // chains by a rule that depends on `units` only, so the result never depends on how passes are sized.
    auto steps_until = [&](long long units, std::size_t c) -> uint64_t {
        const unsigned __int128 all = (unsigned __int128)(units) * (unsigned __int128)(uint64_t(w) * uint64_t(h));
        const auto C = (unsigned __int128)chains.size();
        return uint64_t(all * (c + 1) / C - all * c / C);
    };

    auto pass = [&](long long first, long long n) {
        parallel_for_units(chains.size(), [&](std::size_t c) {
            Chain& ch = chains[c];
            SampleCounters& cnt = counters[c];
            const uint64_t todo = steps_until(first + n, c) - steps_until(first, c);
            // One std::function per pass: built per step, it would allocate (the closure exceeds its small buffer).
            const MarkovChain::Target target = [&](CoordinateSource& src, Slot slot) {
                ch.pss->bind(src);
                return evaluate(*ch.pss, ch.f[int(slot)], cnt);
            };
            for (uint64_t k = 0; k < todo; ++k) {
                if ((k & 255) == 255 && interrupt_requested()) return;
                const StepOutcome o = ch.mc->step(target);
                if (m_waste_recycling) {
                    splat_state(ch.f[0], o.w_x);
                    splat_state(ch.f[1], o.w_y);
                    splat_state(ch.f[2], o.w_z);  // y* (f[3]) is never splatted
                }
                if (o.accepted > 0) {
                    std::swap(ch.f[0], ch.f[o.accepted]);
                    if (!stage_counts.empty()) count_stage(ch.mc->state(), o.accepted);
                }
                if (!m_waste_recycling) splat_state(ch.f[0], 1.0);
                ++ch.steps_done;
                steps_total.fetch_add(1, std::memory_order_relaxed);
            }
        });
    };

    auto develop = [&] {
        Bitmap img = direct.empty() ? Bitmap(w, h) : direct;
        const uint64_t n = steps_total.load();
        if (n > 0) {
            Bitmap m = image.develop(st.normalization / double(n));
            for (std::size_t i = 0; i < img.size(); ++i) img.data()[i] += m.data()[i];
        }
        if (m_delayed_rejection) {
            const int r = img.add_channel("stages.R"), g = img.add_channel("stages.G");
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    const std::size_t k = (std::size_t(y) * std::size_t(w) + std::size_t(x)) * 2;
                    img.at(x, y, r) = float(stage_counts[k].load(std::memory_order_relaxed));
                    img.at(x, y, g) = float(stage_counts[k + 1].load(std::memory_order_relaxed));
                }
        }
        return img;
    };

    Timer tc;
    // Equal-time runs and checkpoints charge the bootstrap and the direct pass.
    const long long target = (long long)std::ceil(m_mutations_per_pixel);
    PassLoopResult loop;
    if (!chains.empty()) loop = run_passes(ctx, target, "mutations/px", pass, develop, total.seconds());
    st.seconds_chains = tc.seconds();

    for (const Chain& ch : chains) st.chain += ch.mc->stats();
    for (const auto& c : counters) st.invalid_contributions += c.invalid;
    st.splat_overflow = image.overflowed();
    st.mutations_per_pixel = double(st.chain.steps) / P;

    RunResult result;
    result.image = develop();
    result.interrupted = loop.interrupted;
    result.seconds = total.seconds();
    result.work = st.mutations_per_pixel;
    result.work_unit = "mutations/px";

    // Statistics: printed by the CLI, readable through statistics().
    report_counters(ctx, counters, "mlt.path_evaluations");
    auto& S = ctx.stats;
    S.set("mlt.normalization", st.normalization);
    S.set("mlt.bootstrap_nonzero_fraction", nboot ? double(st.bootstrap_nonzero) / double(nboot) : 0.0);
    S.add("mlt.mutations", double(st.chain.steps), "mutations");
    S.set("mlt.mutations_per_pixel", st.mutations_per_pixel);
    S.set("mlt.mutations_per_second", st.mutations_per_second());
    S.set("mlt.acceptance.stage1_small", st.stage1_acceptance());
    if (st.chain.evaluations > st.chains)
        S.set("mlt.coordinates_per_state",
              2.0 * double(st.chain.pairs_realised) / double(st.chain.evaluations - st.chains));
    S.set("mlt.acceptance.large_step", st.large_step_acceptance());
    if (m_delayed_rejection) {
        S.set("mlt.acceptance.stage2", st.stage2_acceptance());
        S.add("mlt.stage2_attempts", double(st.chain.stage2_attempted), "attempts");
        S.set("mlt.stage2_time_share", st.stage2_time_share());
        if (type() == DrType::Green) {
            S.add("mlt.ystar_evaluations", double(st.chain.ystar_evaluations), "paths");
            S.add("mlt.ystar_skipped", double(st.chain.ystar_skipped), "paths");
        }
    }
    S.add_time("mlt.time.bootstrap", st.seconds_bootstrap);
    S.add_time("mlt.time.direct", st.seconds_direct);
    S.add_time("mlt.time.chains", st.seconds_chains);
    if (st.splat_overflow > 0) {
        S.add("mlt.splat_overflow", double(st.splat_overflow), "splats");
        log_warn("{}: {} splat(s) out of the accumulator's range were dropped", to_string(), st.splat_overflow);
    }

    // The stage map as a heat map: G / (R + G + 0.01), second-stage share of the acceptances (Fig. 4.1).
    if (m_delayed_rejection && !ctx.output.empty()) {
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

    std::lock_guard lock(m_stats_mutex);
    m_stats = st;
    return result;
}

}  // namespace kelvin
