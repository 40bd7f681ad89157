// The `kelvin` Python module's native part (_kelvin): scenes from files, strings and dicts, renders and simulation
// states as NumPy arrays, progress callbacks and Ctrl-C. The user-facing documentation is docs/python.md; the
// pure-Python package (python/kelvin/__init__.py) re-exports what is here.
//
// Threads and the GIL: every call that does work (a render, a simulation step) runs the C++ job on a worker thread
// with the GIL released, while the calling thread waits in slices of 20 ms, taking the GIL back only to run
// Python's signal handlers (PyErr_CheckSignals). A KeyboardInterrupt there cancels the job's token; the job stops at
// its next poll (docs/cli.md: at most 0.1 s of work), its partial result is attached to the exception as `result`
// and the KeyboardInterrupt propagates. Other Python threads run meanwhile, so two threads can render at once.
#include <kelvin/core/converge.h>
#include <kelvin/core/dict.h>
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/image.h>
#include <kelvin/core/install.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parallel.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/registry.h>
#include <kelvin/core/version.h>
#include <kelvin/fluid/dye.h>
#include <kelvin/fluid/grid.h>
#include <kelvin/fluid/grid3.h>
#include <kelvin/fluid/mcfluid3.h>
#include <kelvin/fluid/simulation.h>
#include <kelvin/fluid/solver.h>

#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <chrono>
#include <exception>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>

namespace py = pybind11;
using namespace kelvin;

namespace {

// ------------------------------------------------------------------------------------------------------- errors

py::object g_error_type;      // kelvin.Error(ValueError): bad input, with file, line, column
py::object g_run_error_type;  // kelvin.RunError(RuntimeError): a run that failed (an output not written, ...)

[[noreturn]] void raise_input_error(const InputError& e) {
    py::object exc = g_error_type(py::str(e.what()));
    const SourceLoc& loc = e.location();
    exc.attr("file") = loc.valid() ? py::object(py::str(loc.file)) : py::none();
    exc.attr("line") = loc.line > 0 ? py::object(py::int_(loc.line)) : py::none();
    exc.attr("column") = loc.column > 0 ? py::object(py::int_(loc.column)) : py::none();
    exc.attr("message") = py::str(e.bare_message());
    PyErr_SetObject(g_error_type.ptr(), exc.ptr());
    throw py::error_already_set();
}

// Runs `f` and turns Kelvin's exceptions into kelvin.Error / kelvin.RunError (needs the GIL).
template <class F>
auto translating(F&& f) -> decltype(f()) {
    try {
        return f();
    } catch (const InputError& e) {
        raise_input_error(e);
    } catch (const kelvin::Error& e) {
        PyErr_SetString(g_run_error_type.ptr(), e.what());
        throw py::error_already_set();
    }
}

// -------------------------------------------------------------------------------------------- arrays and images

// A Bitmap as an array (height, width, channels) of float32 that owns it: no copy.
py::array_t<float> to_array(Bitmap&& bitmap) {
    auto* owned = new Bitmap(std::move(bitmap));
    py::capsule free_when_done(owned, [](void* p) { delete static_cast<Bitmap*>(p); });
    const py::ssize_t h = owned->height(), w = owned->width(), c = owned->channel_count();
    return py::array_t<float>(
        {h, w, c}, {w * c * py::ssize_t(sizeof(float)), c * py::ssize_t(sizeof(float)), py::ssize_t(sizeof(float))},
        owned->data(), free_when_done);
}

Bitmap from_array(const py::array& a, std::optional<std::vector<std::string>> channels) {
    auto arr = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(a);
    if (!arr) throw InputError({}, "write: expected an array of numbers");
    if (arr.ndim() != 2 && arr.ndim() != 3)
        throw InputError({}, fmt::format("write: expected an array of shape (height, width[, channels]), got {} "
                                         "dimensions",
                                         arr.ndim()));
    const int h = int(arr.shape(0)), w = int(arr.shape(1)), c = arr.ndim() == 3 ? int(arr.shape(2)) : 1;
    std::vector<std::string> names;
    if (channels) {
        names = *channels;
        if (int(names.size()) != c)
            throw InputError({}, fmt::format("write: {} channel names for an array of {} channels", names.size(), c));
    } else if (c == 1) {
        names = {"Y"};
    } else if (c == 3 || c == 4) {
        names = {"R", "G", "B"};
        if (c == 4) names.push_back("A");
    } else {
        for (int i = 0; i < c; ++i) names.push_back(fmt::format("C{}", i));
    }
    Bitmap b(w, h, names);
    std::copy(arr.data(), arr.data() + std::size_t(w) * std::size_t(h) * std::size_t(c), b.data());
    return b;
}

py::dict stats_dict(const Stats& stats) {
    py::dict d;
    for (const auto& c : stats.counters()) d[py::str(c.name)] = c.value;
    return d;
}

py::dict progress_dict(const ProgressInfo& p) {
    py::dict d;
    d["label"] = p.label;
    d["done"] = p.done;
    d["total"] = p.total;
    d["unit"] = p.unit;
    d["seconds"] = p.seconds;
    d["time_limit"] = p.time_limit;
    d["nested"] = p.nested;
    d["final"] = p.final;
    d["interrupted"] = p.interrupted;
    d["fraction"] = p.fraction();
    return d;
}

// ------------------------------------------------------------------------------------------------------ scenes

/// A loaded scene: the object tree and, for messages, where it came from.
struct Scene {
    ObjectPtr root;
    std::string source;
    std::shared_ptr<Job> job() const {
        auto j = std::dynamic_pointer_cast<Job>(root);
        if (!j)
            throw InputError({}, fmt::format("{}: the scene is not runnable (no integrator or simulation)", source));
        return j;
    }
};

ParseOptions parse_options(const py::kwargs& params) {
    ParseOptions opts;
    for (const auto& [k, v] : params) {
        const std::string name = py::str(k);
        std::string value;
        if (py::isinstance<py::bool_>(v))
            value = v.cast<bool>() ? "true" : "false";
        else
            value = py::str(v);
        opts.defines[name] = value;
    }
    return opts;
}

Scene load_parsed(const ParsedScene& parsed, bool allow_unused, const std::string& source) {
    check_defines(parsed, allow_unused, "allow_unused=True ignores it");
    InstantiateOptions iopts;
    iopts.allow_unused = allow_unused;
    iopts.unused_hint = "pass allow_unused=True to ignore";
    return {instantiate(parsed, iopts), source};
}

// Python values to a Dict value, with Mitsuba 3's conventions: nested dicts are objects ("type"), {"type": "rgb",
// "value": ...} a colour, {"type": "ref", "id": ...} a reference, a 3-sequence a triple (colour, point or vector, as
// the parameter is declared), a 4x4 nested sequence (or array) a transform.
DictValue to_dict_value(const py::handle& v, const std::string& path);

Dict to_dict(const py::dict& d, const std::string& path) {
    Dict out;
    for (const auto& [k, v] : d) {
        if (!py::isinstance<py::str>(k))
            throw InputError({"dict:" + path, 0, 0},
                             fmt::format("keys must be strings, got {}", std::string(py::str(py::type::of(k)))));
        const std::string key = py::str(k);
        out.set(key, to_dict_value(v, path.empty() ? key : path + "." + key));
    }
    return out;
}

std::optional<Mat4d> as_matrix(const py::handle& v) {
    try {
        auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(v);
        if (!a || a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4) return std::nullopt;
        Mat4d m(1.0);
        for (int r = 0; r < 4; ++r)
            for (int c = 0; c < 4; ++c) m[c][r] = a.at(r, c);  // glm is column-major
        return m;
    } catch (const py::error_already_set&) {
        return std::nullopt;
    }
}

DictValue to_dict_value(const py::handle& v, const std::string& path) {
    const SourceLoc loc{"dict:" + path, 0, 0};
    if (py::isinstance<py::bool_>(v)) return DictValue(v.cast<bool>());
    if (py::isinstance<py::int_>(v)) {
        try {
            return DictValue(v.cast<long long>());
        } catch (const py::cast_error&) {
            throw InputError(loc, "integer out of range");
        }
    }
    if (py::isinstance<py::float_>(v)) return DictValue(v.cast<double>());
    if (py::isinstance<py::str>(v)) return DictValue(v.cast<std::string>());
    if (py::isinstance<Transform>(v)) return DictValue(v.cast<Transform>());
    if (py::isinstance<dict::Rgb>(v)) return DictValue(v.cast<dict::Rgb>());
    if (py::isinstance<dict::Point>(v)) return DictValue(v.cast<dict::Point>());
    if (py::isinstance<dict::Vector>(v)) return DictValue(v.cast<dict::Vector>());
    if (py::isinstance<Scene>(v)) return DictValue(v.cast<Scene&>().root);
    if (py::isinstance<py::dict>(v)) {
        const py::dict d = py::reinterpret_borrow<py::dict>(v);
        if (d.contains("type")) {
            const std::string type = py::str(d["type"]);
            if (type == "rgb") {
                if (!d.contains("value")) throw InputError(loc, "an rgb needs a 'value'");
                const py::handle value = d["value"];
                if (py::isinstance<py::float_>(value) || py::isinstance<py::int_>(value))
                    return DictValue(dict::rgb(value.cast<double>()));
                const auto t = value.cast<std::vector<double>>();
                if (t.size() != 3) throw InputError(loc, "an rgb 'value' needs 3 numbers");
                return DictValue(dict::rgb(t[0], t[1], t[2]));
            }
            if (type == "ref") {
                if (!d.contains("id")) throw InputError(loc, "a ref needs an 'id'");
                return DictValue(dict::ref(py::str(d["id"])));
            }
        }
        return DictValue(to_dict(d, path));
    }
    if (auto m = as_matrix(v)) return DictValue(Transform(*m));
    if (py::isinstance<py::sequence>(v) || py::isinstance<py::array>(v)) {
        std::vector<double> t;
        try {
            t = v.cast<std::vector<double>>();
        } catch (const py::cast_error&) {
            throw InputError(loc, "a sequence must hold 3 numbers (a colour, point or vector) or be a 4 x 4 matrix");
        }
        if (t.size() != 3)
            throw InputError(loc, fmt::format("a sequence of {} numbers: expected 3 (a colour, point or vector) or a "
                                              "4 x 4 matrix",
                                              t.size()));
        return DictValue(Vec3d(t[0], t[1], t[2]));
    }
    throw InputError(loc, fmt::format("a value of type {} cannot be a scene parameter",
                                      std::string(py::str(py::type::of(v).attr("__name__")))));
}

// ------------------------------------------------------------------------------------------- running C++ work

/// Runs `work` on a worker thread with the GIL released; the caller's thread runs Python's signal handlers every
/// 20 ms. A KeyboardInterrupt (or another exception from a handler) cancels `cancel` and is re-raised once the work
/// has stopped, with `on_interrupt(result)` attached to it. A progress callback is called with the GIL held.
template <class R>
R run_interruptibly(const std::function<R()>& work, const CancelToken& cancel,
                    const std::function<py::object(R&)>& attach = {}) {
    std::packaged_task<R()> task(work);
    std::future<R> done = task.get_future();
    std::optional<py::error_already_set> pending;
    {
        py::gil_scoped_release release;
        std::thread worker(std::move(task));
        while (done.wait_for(std::chrono::milliseconds(20)) != std::future_status::ready) {
            if (pending) continue;
            py::gil_scoped_acquire acquire;
            if (PyErr_CheckSignals() != 0) {
                pending.emplace();  // fetches the KeyboardInterrupt
                cancel.cancel();
            }
        }
        worker.join();
    }
    R result = translating([&] { return done.get(); });
    if (pending) {
        if (attach) {
            py::object partial = attach(result);
            try {
                pending->value().attr("result") = partial;
            } catch (const py::error_already_set&) {
            }
        }
        pending->restore();
        throw py::error_already_set();
    }
    return result;
}

/// A progress callback from Python, called with the GIL; an exception it raises cancels the job and is re-raised.
struct ProgressForwarder {
    py::object callable;
    CancelToken cancel;
    std::shared_ptr<std::optional<py::error_already_set>> error =
        std::make_shared<std::optional<py::error_already_set>>();

    ProgressCallback callback() const {
        if (callable.is_none()) return {};
        return [fn = callable, cancel = cancel, error = error](const ProgressInfo& p) {
            py::gil_scoped_acquire acquire;
            if (*error) return;
            try {
                fn(progress_dict(p));
            } catch (py::error_already_set& e) {
                error->emplace(std::move(e));
                cancel.cancel();
            }
        };
    }
    void rethrow() const {
        if (*error) {
            (*error)->restore();
            throw py::error_already_set();
        }
    }
};

struct Result {
    py::object image;  // ndarray (height, width, channels), or None
    std::vector<std::string> channels;
    py::dict stats;
    bool interrupted = false;
    double seconds = 0, work = 0;
    std::string work_unit, description;
};

Result to_result(RunResult&& r, const Stats& stats, const std::string& description) {
    Result out;
    out.channels = r.image.channels();
    out.image = r.image.empty() ? py::object(py::none()) : py::object(to_array(std::move(r.image)));
    out.stats = stats_dict(stats);
    out.interrupted = r.interrupted;
    out.seconds = r.seconds;
    out.work = r.work;
    out.work_unit = r.work_unit;
    out.description = r.description.empty() ? description : r.description;
    return out;
}

struct RunSettings {
    std::optional<long long> spp;
    uint64_t seed = 0;
    std::optional<int> threads;
    std::optional<double> time_limit;
};

RunSettings settings(std::optional<long long> spp, py::object seed, std::optional<int> threads,
                     std::optional<double> time_limit) {
    RunSettings s;
    if (spp && (*spp < 1 || *spp > (1LL << 40)))
        throw InputError({}, fmt::format("spp={}: must be in [1, 2^40]", *spp));
    s.spp = spp;
    try {
        const py::int_ i = py::reinterpret_borrow<py::int_>(seed);
        if (!py::isinstance<py::int_>(seed) || py::isinstance<py::bool_>(seed)) throw py::cast_error();
        if (i < py::int_(0)) throw py::cast_error();
        s.seed = seed.cast<uint64_t>();
    } catch (const py::cast_error&) {
        throw InputError(
            {}, fmt::format("seed={}: expected a whole number from 0 to 2^64 - 1", std::string(py::repr(seed))));
    }
    if (threads && (*threads < 0 || *threads > 4096))
        throw InputError({}, fmt::format("threads={}: must be in [0, 4096]", *threads));
    s.threads = threads;
    if (time_limit && !(std::isfinite(*time_limit) && *time_limit >= 0))
        throw InputError({}, fmt::format("time_limit={}: must be a finite number >= 0", *time_limit));
    s.time_limit = time_limit;
    return s;
}

Result run_scene(const Scene& scene, std::optional<long long> spp, py::object seed, std::optional<int> threads,
                 std::optional<double> time_limit, py::object progress,
                 std::optional<std::filesystem::path> output = std::nullopt) {
    const RunSettings s = translating([&] { return settings(spp, seed, threads, time_limit); });
    const std::shared_ptr<Job> job = translating([&] { return scene.job(); });
    auto ctx = std::make_shared<RunContext>();
    ctx->seed = s.seed;
    ctx->spp = s.spp.value_or(-1);
    ctx->time_limit = s.time_limit.value_or(0);
    ctx->quiet = true;
    if (output) {
        // What the job writes beside its image (a simulation's frames and CSV, an MLT stage map) goes there.
        translating([&] {
            if (std::string why = output_file_problem(*output); !why.empty())
                throw InputError({}, fmt::format("output '{}': {}", output->string(), why));
            return 0;
        });
        ctx->output = *output;
    }
    ProgressForwarder forward{progress, ctx->cancel};
    ctx->on_progress = forward.callback();
    const int nthreads = s.threads.value_or(0);
    auto result = run_interruptibly<Result>(
        [&]() -> Result {
            std::optional<ThreadLimit> limit;
            if (nthreads > 0) limit.emplace(nthreads);
            RunResult r = job->run(*ctx);
            py::gil_scoped_acquire acquire;  // arrays and dicts are Python objects
            return to_result(std::move(r), ctx->stats, job->description());
        },
        ctx->cancel, [](Result& r) { return py::cast(r); });
    forward.rethrow();
    return result;
}

// --------------------------------------------------------------------------------------------------- simulations

/// A simulation stepped from Python: the solver of the scene's <simulation> (2D or 3D), at t = 0.
class PySimulation {
public:
    PySimulation(const Scene& scene, py::object seed, std::optional<long long> spp, std::optional<int> threads) {
        translating([&] {
            m_scene = scene;
            m_sim = fluid::find_simulation(scene.root);
            const RunSettings s = settings(spp, seed, threads, std::nullopt);
            m_threads = s.threads.value_or(0);
            m_ctx.seed = s.seed;
            m_ctx.spp = s.spp.value_or(-1);
            m_ctx.quiet = true;
            m_steps = m_sim->time_stepping();
            if (m_sim->dimension() == 3)
                m_solver3 = m_sim->create_solver3(m_ctx);
            else
                m_solver2 = m_sim->create_solver(m_ctx);
            return 0;
        });
    }

    int dimension() const { return m_sim->dimension(); }
    double time() const { return m_solver3 ? m_solver3->time() : m_solver2->time(); }
    long long step_index() const { return m_solver3 ? m_solver3->step_index() : m_solver2->step_index(); }
    long long steps() const { return m_steps.steps; }
    double dt() const { return m_steps.dt; }
    double end_time() const { return m_steps.end_time > 0 ? m_steps.end_time : double(m_steps.steps) * m_steps.dt; }

    /// One step: `dt`, or the scene's step length (the last one landing on the end time, as run() steps).
    bool step(std::optional<double> dt) {
        if (dt && !(std::isfinite(*dt) && *dt > 0))
            translating([&]() -> int { throw InputError({}, fmt::format("dt={}: must be finite and > 0", *dt)); });
        const double h = dt ? *dt : m_steps.step_length(step_index() + 1, time());
        m_ctx.cancel.reset();
        const int nthreads = m_threads;
        return run_interruptibly<bool>(
            [&] {
                std::optional<ThreadLimit> limit;
                if (nthreads > 0) limit.emplace(nthreads);
                return m_solver3 ? m_solver3->step(h) : m_solver2->step(h);
            },
            m_ctx.cancel);
    }

    /// Steps until the scene's end (or `t`); returns the steps taken.
    long long run(std::optional<double> until, py::object progress) {
        const double end = until ? *until : end_time();
        long long taken = 0;
        while (time() < end - 1e-12 * std::max(1.0, std::abs(end))) {
            const double h = std::min(m_steps.step_length(step_index() + 1, time()), end - time());
            if (!step(h)) break;
            ++taken;
            if (!progress.is_none()) progress(py::dict(py::arg("step") = step_index(), py::arg("time") = time()));
        }
        return taken;
    }

    py::array vorticity() {
        if (m_solver3) return vector_grid(m_solver3->vorticity_grid());
        return scalar_grid(m_solver2->vorticity_grid());
    }
    py::array velocity() {
        if (m_solver3) {
            const fluid::VectorGrid3* v =
                run_interruptibly<const fluid::VectorGrid3*>([&] { return &m_solver3->velocity_grid(); }, m_ctx.cancel);
            return vector_grid(*v);
        }
        const fluid::Grid2& u = m_solver2->velocity_u();
        const fluid::Grid2& w = m_solver2->velocity_v();
        py::array_t<double> a({py::ssize_t(u.ny()), py::ssize_t(u.nx()), py::ssize_t(2)});
        auto m = a.mutable_unchecked<3>();
        for (int j = 0; j < u.ny(); ++j)
            for (int i = 0; i < u.nx(); ++i) m(j, i, 0) = u.at(i, j), m(j, i, 1) = w.at(i, j);
        return a;
    }
    /// 2D: the dye channels {name: (ny, nx)}; 3D: {"smoke": (nz, ny, nx)} when the scene has smoke.
    py::dict scalars() {
        py::dict d;
        if (m_solver3) {
            if (const fluid::Grid3* s = m_solver3->smoke()) d["smoke"] = scalar_grid3(*s);
        } else if (fluid::PassiveScalars* dye = m_solver2->dye()) {
            for (int c = 0; c < dye->channel_count(); ++c)
                d[py::str(dye->channel_names()[std::size_t(c)])] = scalar_grid(dye->channel(c));
        }
        return d;
    }
    py::array cell_centers() {
        if (m_solver3) {
            const fluid::Grid3& g = m_solver3->vorticity_grid().x;
            py::array_t<double> a({py::ssize_t(g.nz()), py::ssize_t(g.ny()), py::ssize_t(g.nx()), py::ssize_t(3)});
            auto m = a.mutable_unchecked<4>();
            for (int k = 0; k < g.nz(); ++k)
                for (int j = 0; j < g.ny(); ++j)
                    for (int i = 0; i < g.nx(); ++i) {
                        const Vec3d c = g.cell_center(i, j, k);
                        for (int x = 0; x < 3; ++x) m(k, j, i, x) = c[x];
                    }
            return a;
        }
        const fluid::Grid2& g = m_solver2->vorticity_grid();
        py::array_t<double> a({py::ssize_t(g.ny()), py::ssize_t(g.nx()), py::ssize_t(2)});
        auto m = a.mutable_unchecked<3>();
        for (int j = 0; j < g.ny(); ++j)
            for (int i = 0; i < g.nx(); ++i) {
                const Vec2d c = g.cell_center(i, j);
                m(j, i, 0) = c.x, m(j, i, 1) = c.y;
            }
        return a;
    }

    py::array velocity_at(const py::array& points) { return pointwise(points, true); }
    py::array vorticity_at(const py::array& points) { return pointwise(points, false); }

    py::dict diagnostics() {
        py::dict d;
        if (m_solver3) {
            const fluid::FluidDiagnostics3 g =
                run_interruptibly<fluid::FluidDiagnostics3>([&] { return m_solver3->diagnostics(); }, m_ctx.cancel);
            d["step"] = g.step, d["time"] = g.time, d["kinetic_energy"] = g.kinetic_energy;
            d["kinetic_energy_raw"] = g.kinetic_energy_raw, d["enstrophy"] = g.enstrophy, d["helicity"] = g.helicity;
            d["impulse"] = py::make_tuple(g.impulse.x, g.impulse.y, g.impulse.z);
            d["centroid"] = py::make_tuple(g.centroid.x, g.centroid.y, g.centroid.z);
            d["max_abs_vorticity"] = g.max_abs_vorticity, d["divergence_rms"] = g.divergence_rms;
            d["smoke_mass"] = g.smoke_mass;
            return d;
        }
        const fluid::FluidDiagnostics g =
            run_interruptibly<fluid::FluidDiagnostics>([&] { return m_solver2->diagnostics(); }, m_ctx.cancel);
        d["step"] = g.step, d["time"] = g.time, d["kinetic_energy"] = g.kinetic_energy;
        d["kinetic_energy_raw"] = g.kinetic_energy_raw, d["enstrophy"] = g.enstrophy, d["circulation"] = g.circulation;
        d["max_abs_vorticity"] = g.max_abs_vorticity, d["vorticity_rmse_exact"] = g.vorticity_rmse_exact;
        return d;
    }

private:
    static py::array scalar_grid(const fluid::Grid2& g) {
        py::array_t<double> a({py::ssize_t(g.ny()), py::ssize_t(g.nx())});
        std::copy(g.values().begin(), g.values().end(), a.mutable_data());
        return a;
    }
    static py::array scalar_grid3(const fluid::Grid3& g) {
        py::array_t<double> a({py::ssize_t(g.nz()), py::ssize_t(g.ny()), py::ssize_t(g.nx())});
        std::copy(g.values().begin(), g.values().end(), a.mutable_data());
        return a;
    }
    // (nz, ny, nx, 3): cell (i, j, k) at [k, j, i], as the grids store their values (x fastest).
    static py::array vector_grid(const fluid::VectorGrid3& g) {
        const fluid::Grid3& gx = g.x;
        py::array_t<double> a({py::ssize_t(gx.nz()), py::ssize_t(gx.ny()), py::ssize_t(gx.nx()), py::ssize_t(3)});
        double* out = a.mutable_data();
        for (std::size_t c = 0; c < g.cell_count(); ++c) {
            const Vec3d v = g.at(c);
            out[3 * c] = v.x, out[3 * c + 1] = v.y, out[3 * c + 2] = v.z;
        }
        return a;
    }

    py::array pointwise(const py::array& points, bool velocity) {
        const int D = dimension();
        auto p = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(points);
        if (!p || p.ndim() != 2 || p.shape(1) != D)
            translating(
                [&]() -> int { throw InputError({}, fmt::format("points: expected an array of shape (N, {})", D)); });
        const py::ssize_t n = p.shape(0);
        const int out_dim = velocity ? D : (D == 3 ? 3 : 1);
        std::vector<double> out(std::size_t(n) * std::size_t(out_dim));
        const double* in = p.data();
        run_interruptibly<int>(
            [&] {
                parallel_for_units(std::size_t(n), [&](std::size_t q) {
                    const double* x = in + q * std::size_t(D);
                    double* y = out.data() + q * std::size_t(out_dim);
                    if (D == 3) {
                        const Vec3d r = velocity ? m_solver3->velocity_at(Vec3d(x[0], x[1], x[2]))
                                                 : m_solver3->vorticity_at(Vec3d(x[0], x[1], x[2]));
                        y[0] = r.x, y[1] = r.y, y[2] = r.z;
                    } else if (velocity) {
                        const Vec2d r = m_solver2->velocity_at(Vec2d(x[0], x[1]));
                        y[0] = r.x, y[1] = r.y;
                    } else {
                        y[0] = m_solver2->vorticity_at(Vec2d(x[0], x[1]));
                    }
                });
                return 0;
            },
            m_ctx.cancel);
        py::array_t<double> a =
            out_dim == 1 ? py::array_t<double>({n}) : py::array_t<double>({n, py::ssize_t(out_dim)});
        std::copy(out.begin(), out.end(), a.mutable_data());
        return a;
    }

    Scene m_scene;
    std::shared_ptr<fluid::Simulation> m_sim;
    fluid::TimeStepping m_steps;
    RunContext m_ctx;
    int m_threads = 0;
    std::unique_ptr<fluid::FluidSolver> m_solver2;
    std::unique_ptr<fluid::MCFluid3Solver> m_solver3;
};

}  // namespace

PYBIND11_MODULE(_kelvin, m) {
    m.doc() = "Kelvin: Monte Carlo light transport and Monte Carlo fluid simulation (docs/python.md)";
    m.attr("__version__") = KELVIN_VERSION_STRING;
    set_log_level(LogLevel::Warn);

    g_error_type = py::reinterpret_steal<py::object>(
        PyErr_NewExceptionWithDoc("kelvin.Error",
                                  "Bad input: a scene, a parameter, a file. `file`, `line`, `column` say where "
                                  "(None when unknown); `message` is the text without the location.",
                                  PyExc_ValueError, nullptr));
    g_run_error_type = py::reinterpret_steal<py::object>(PyErr_NewExceptionWithDoc(
        "kelvin.RunError", "A run that failed: an output that could not be written, numerical trouble.",
        PyExc_RuntimeError, nullptr));
    m.attr("Error") = g_error_type;
    m.attr("RunError") = g_run_error_type;

    py::class_<Transform>(m, "Transform", "A 4 x 4 affine transform (the XML's <transform>); A @ B applies B first.")
        .def(py::init([](const py::object& matrix) {
                 auto mat = as_matrix(matrix);
                 if (!mat) throw py::value_error("Transform: expected a 4 x 4 matrix");
                 return Transform(*mat);
             }),
             py::arg("matrix"))
        .def_static("translate",
                    [](std::array<double, 3> t) {
                        return Transform::translate({t[0], t[1], t[2]});
                    })
        .def_static("scale",
                    [](const py::object& s) {
                        if (py::isinstance<py::float_>(s) || py::isinstance<py::int_>(s))
                            return Transform::scale(Vec3d(s.cast<double>()));
                        const auto v = s.cast<std::array<double, 3>>();
                        return Transform::scale({v[0], v[1], v[2]});
                    })
        .def_static("rotate",
                    [](std::array<double, 3> axis, double degrees) {
                        return Transform::rotate({axis[0], axis[1], axis[2]}, degrees);
                    })
        .def_static(
            "look_at",
            [](std::array<double, 3> o, std::array<double, 3> t, std::array<double, 3> up) {
                return Transform::look_at({o[0], o[1], o[2]}, {t[0], t[1], t[2]}, {up[0], up[1], up[2]});
            },
            py::arg("origin"), py::arg("target"), py::arg("up"))
        .def("__matmul__", [](const Transform& a, const Transform& b) { return a * b; })
        .def_property_readonly("matrix", [](const Transform& t) {
            py::array_t<double> a({4, 4});
            auto m = a.mutable_unchecked<2>();
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) m(r, c) = t.matrix[c][r];
            return a;
        });
    py::class_<dict::Rgb>(m, "_Rgb");
    py::class_<dict::Point>(m, "_Point");
    py::class_<dict::Vector>(m, "_Vector");
    m.def(
        "rgb",
        [](double r, std::optional<double> g, std::optional<double> b) {
            return g && b ? dict::rgb(r, *g, *b) : dict::rgb(r);
        },
        py::arg("r"), py::arg("g") = py::none(), py::arg("b") = py::none(), "An RGB value for load_dict (XML <rgb>).");
    m.def(
        "point", [](double x, double y, double z) { return dict::point(x, y, z); }, py::arg("x"), py::arg("y"),
        py::arg("z") = 0.0, "A point for load_dict (XML <point>).");
    m.def(
        "vector", [](double x, double y, double z) { return dict::vector(x, y, z); }, py::arg("x"), py::arg("y"),
        py::arg("z") = 0.0, "A vector for load_dict (XML <vector>).");

    py::class_<Scene>(m, "Scene", "A loaded scene: a render or a simulation.")
        .def_property_readonly("description", [](const Scene& s) { return s.root->description(); })
        .def_property_readonly("is_simulation",
                               [](const Scene& s) {
                                   try {
                                       fluid::find_simulation(s.root);
                                       return true;
                                   } catch (const InputError&) {
                                       return false;
                                   }
                               })
        .def("__repr__",
             [](const Scene& s) { return fmt::format("<kelvin.Scene {} ({})>", s.root->description(), s.source); });

    m.def(
        "load_file",
        [](const std::filesystem::path& path, bool allow_unused, const py::kwargs& params) {
            return translating([&] {
                const ParsedScene parsed = parse_scene_file(path, parse_options(params));
                return load_parsed(parsed, allow_unused, path.string());
            });
        },
        py::arg("path"), py::kw_only(), py::arg("allow_unused") = false,
        "Load an XML scene; keyword arguments set its <default> parameters (as kelvin -D NAME=VALUE).");
    m.def(
        "load_string",
        [](const std::string& xml, bool allow_unused, const py::kwargs& params) {
            return translating([&] {
                const ParsedScene parsed = parse_scene_string(xml, parse_options(params));
                return load_parsed(parsed, allow_unused, "<string>");
            });
        },
        py::arg("xml"), py::kw_only(), py::arg("allow_unused") = false, "Load a scene from XML text.");
    m.def(
        "load_dict",
        [](const py::dict& d, bool allow_unused, std::optional<std::filesystem::path> base_dir) {
            return translating([&] {
                DictOptions opts;
                opts.allow_unused = allow_unused;
                if (base_dir) opts.base_dir = *base_dir;
                return Scene{load_dict(to_dict(d, ""), opts), "dict"};
            });
        },
        py::arg("dict"), py::kw_only(), py::arg("allow_unused") = false, py::arg("base_dir") = py::none(),
        "Build a scene (or any object) from a dict with Mitsuba 3's conventions.");

    py::class_<Result>(m, "Result", "What run() returns: the image, its channels, the statistics.")
        .def_readonly("image", &Result::image)
        .def_readonly("channels", &Result::channels)
        .def_readonly("stats", &Result::stats)
        .def_readonly("interrupted", &Result::interrupted)
        .def_readonly("seconds", &Result::seconds)
        .def_readonly("work", &Result::work)
        .def_readonly("work_unit", &Result::work_unit)
        .def_readonly("description", &Result::description)
        .def("__repr__", [](const Result& r) {
            return fmt::format("<kelvin.Result {}: {:g} {} in {:.3f} s{}>", r.description, r.work, r.work_unit,
                               r.seconds, r.interrupted ? ", interrupted" : "");
        });
    m.def("run", &run_scene, py::arg("scene"), py::kw_only(), py::arg("spp") = py::none(), py::arg("seed") = 0,
          py::arg("threads") = py::none(), py::arg("time_limit") = py::none(), py::arg("progress") = py::none(),
          py::arg("output") = py::none(),
          "Run a scene (a render or a whole simulation): a Result. `output`: the path the CLI's -o would be; what the "
          "job writes beside it (a simulation's frames and diagnostics, an MLT stage map) goes there; the image "
          "itself is not written (kelvin.write does that).");
    m.def(
        "_converge",
        [](const std::filesystem::path& scene,
           const std::vector<std::pair<std::string, std::map<std::string, std::string>>>& configs,
           const std::map<std::string, std::string>& defines, std::optional<std::filesystem::path> reference,
           std::vector<double> seconds, std::vector<long long> spp, std::vector<long long> steps,
           std::vector<double> times, int runs, py::object seed, std::vector<std::string> fields,
           std::optional<std::array<double, 4>> window, std::optional<std::array<double, 3>> disk,
           std::optional<std::array<int, 4>> pixels, double epsilon, const std::filesystem::path& output,
           const std::string& images, bool allow_unused, std::optional<int> threads) {
            ConvergeOptions o;
            translating([&] {
                o.scene = scene;
                o.defines = defines;
                for (const auto& [name, params] : configs) {
                    ConvergeConfig c;
                    c.name = name;
                    for (const auto& kv : params) c.defines.push_back(kv);
                    o.configs.push_back(std::move(c));
                }
                if (runs < 1) throw InputError({}, fmt::format("runs={}: must be at least 1", runs));
                o.runs = runs;
                o.seed = settings(std::nullopt, seed, threads, std::nullopt).seed;
                auto sorted = [](auto v) {
                    std::sort(v.begin(), v.end());
                    v.erase(std::unique(v.begin(), v.end()), v.end());
                    return v;
                };
                for (double x : seconds)
                    if (!(std::isfinite(x) && x >= 0)) throw InputError({}, "checkpoints: finite numbers >= 0");
                for (double x : times)
                    if (!(std::isfinite(x) && x >= 0)) throw InputError({}, "times: finite numbers >= 0");
                o.seconds = sorted(seconds);
                o.spp = sorted(spp);
                o.steps = sorted(steps);
                o.sim_times = sorted(times);
                if (reference) o.reference = *reference;
                if (!fields.empty()) o.fields = fields;
                if (window) o.region = FieldRegion::box({(*window)[0], (*window)[1]}, {(*window)[2], (*window)[3]});
                if (disk) {
                    const FieldRegion box = o.region;
                    o.region = FieldRegion::disk({(*disk)[0], (*disk)[1]}, (*disk)[2]);
                    o.region.use_box = box.use_box, o.region.box_min = box.box_min, o.region.box_max = box.box_max;
                }
                o.window = pixels;
                if (!(epsilon > 0) || !std::isfinite(epsilon)) throw InputError({}, "epsilon: must be finite and > 0");
                o.epsilon = epsilon;
                o.output_dir = output;
                if (images != "none" && images != "first" && images != "all")
                    throw InputError({}, fmt::format("images='{}': none, first or all", images));
                o.images = images == "none"  ? ConvergeOptions::Images::None
                           : images == "all" ? ConvergeOptions::Images::All
                                             : ConvergeOptions::Images::First;
                o.allow_unused = allow_unused;
                o.quiet = true;
                return 0;
            });
            const int nthreads = threads.value_or(0);
            const ConvergeSummary s = run_interruptibly<ConvergeSummary>(
                [&] {
                    std::optional<ThreadLimit> limit;
                    if (nthreads > 0) limit.emplace(nthreads);
                    return run_convergence(o);
                },
                o.cancel);
            return py::make_tuple(s.csv, s.stats_csv, s.interrupted, s.runs_done, s.runs_skipped);
        },
        py::arg("scene"), py::arg("configs"), py::arg("defines"), py::arg("reference"), py::arg("seconds"),
        py::arg("spp"), py::arg("steps"), py::arg("times"), py::arg("runs"), py::arg("seed"), py::arg("fields"),
        py::arg("window"), py::arg("disk"), py::arg("pixels"), py::arg("epsilon"), py::arg("output"), py::arg("images"),
        py::arg("allow_unused"), py::arg("threads"));
    m.def(
        "render",
        [](const Scene& scene, std::optional<long long> spp, py::object seed, std::optional<int> threads,
           std::optional<double> time_limit, py::object progress) {
            return run_scene(scene, spp, std::move(seed), threads, time_limit, std::move(progress)).image;
        },
        py::arg("scene"), py::kw_only(), py::arg("spp") = py::none(), py::arg("seed") = 0,
        py::arg("threads") = py::none(), py::arg("time_limit") = py::none(), py::arg("progress") = py::none(),
        "Render a scene: a float32 array (height, width, channels).");
    m.def(
        "write",
        [](const std::filesystem::path& path, const py::array& image, std::optional<std::vector<std::string>> channels,
           double exposure) {
            translating([&] {
                if (std::string why = output_file_problem(path); !why.empty())
                    throw InputError({}, fmt::format("write '{}': {}", path.string(), why));
                Bitmap b = from_array(image, channels);
                py::gil_scoped_release release;
                write_image(path, b, {exposure, {}});
                return 0;
            });
        },
        py::arg("path"), py::arg("image"), py::kw_only(), py::arg("channels") = py::none(), py::arg("exposure") = 0.0,
        "Write an array (height, width[, channels]) as EXR, PNG, PFM, ... by the extension.");
    m.def(
        "read",
        [](const std::filesystem::path& path) { return translating([&] { return to_array(read_image(path)); }); },
        py::arg("path"), "Read an image: a float32 array (height, width, channels).");
    m.def(
        "read_channels",
        [](const std::filesystem::path& path) { return translating([&] { return read_image(path).channels(); }); },
        py::arg("path"), "The channel names of an image file.");

    m.def(
        "data_directory", [] { return data_directory(); },
        "Kelvin's data directory (scenes, examples, docs, tools): the installation's share/kelvin, the build tree's "
        "mirror of it, or $KELVIN_DATA_DIR.");

    py::class_<PySimulation>(m, "Simulation", "A fluid simulation stepped from Python.")
        .def(py::init<const Scene&, py::object, std::optional<long long>, std::optional<int>>(), py::arg("scene"),
             py::kw_only(), py::arg("seed") = 0, py::arg("spp") = py::none(), py::arg("threads") = py::none())
        .def_property_readonly("dimension", &PySimulation::dimension)
        .def_property_readonly("time", &PySimulation::time)
        .def_property_readonly("step_index", &PySimulation::step_index)
        .def_property_readonly("steps", &PySimulation::steps)
        .def_property_readonly("dt", &PySimulation::dt)
        .def_property_readonly("end_time", &PySimulation::end_time)
        .def("step", &PySimulation::step, py::arg("dt") = py::none())
        .def("run", &PySimulation::run, py::arg("until") = py::none(), py::kw_only(), py::arg("progress") = py::none())
        .def("vorticity", &PySimulation::vorticity)
        .def("velocity", &PySimulation::velocity)
        .def("scalars", &PySimulation::scalars)
        .def("cell_centers", &PySimulation::cell_centers)
        .def("velocity_at", &PySimulation::velocity_at, py::arg("points"))
        .def("vorticity_at", &PySimulation::vorticity_at, py::arg("points"))
        .def("diagnostics", &PySimulation::diagnostics);
}
