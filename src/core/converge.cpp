// Convergence studies (include/kelvin/core/converge.h, docs/convergence.md).
#include <kelvin/core/converge.h>
#include <kelvin/core/distributed.h>
#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/image.h>
#include <kelvin/core/interrupt.h>
#include <kelvin/core/job.h>
#include <kelvin/core/logging.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/strings.h>

#include <fmt/format.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>

namespace fs = std::filesystem;

namespace kelvin {

// ------------------------------------------------------------------------------------------ input parsing

std::string ConvergeConfig::defines_string() const {
    std::string s;
    for (const auto& [k, v] : defines) s += fmt::format("{}{}={}", s.empty() ? "" : ";", k, v);
    return s;
}

namespace {

bool valid_define_name(const std::string& n) {
    if (n.empty()) return false;
    return std::all_of(n.begin(), n.end(), [](char c) { return std::isalnum((unsigned char)c) || c == '_'; });
}

std::pair<std::string, std::string> parse_define(std::string_view kv, const std::string& what) {
    const auto eq = kv.find('=');
    const std::string name(trim(kv.substr(0, eq == std::string_view::npos ? kv.size() : eq)));
    if (eq == std::string_view::npos || !valid_define_name(name))
        throw InputError({}, fmt::format("{}: expected NAME=VALUE, got '{}'", what, std::string(kv)));
    return {name, std::string(trim(kv.substr(eq + 1)))};
}

void check_config_name(const std::string& name, const std::string& what) {
    if (name.empty()) throw InputError({}, fmt::format("{}: empty configuration name", what));
    for (char c : name)
        if (c == '\n' || c == '\r' || c == '"' || std::iscntrl((unsigned char)c))
            throw InputError({}, fmt::format("{}: the configuration name may not contain quotes or control "
                                             "characters",
                                             what));
}

}  // namespace

ConvergeConfig parse_config_spec(const std::string& spec, const std::string& what) {
    ConvergeConfig c;
    std::string_view rest = spec;
    const auto colon = spec.find(':');
    if (colon != std::string::npos) {
        c.name = std::string(trim(std::string_view(spec).substr(0, colon)));
        rest = std::string_view(spec).substr(colon + 1);
    }
    for (const auto& piece : split_list(rest)) c.defines.push_back(parse_define(piece, what));
    if (colon == std::string::npos) {
        if (c.defines.empty()) throw InputError({}, fmt::format("{}: expected NAME:K=V,... or K=V,...", what));
        c.name = std::string(trim(spec));
    }
    check_config_name(c.name, what);
    return c;
}

std::vector<ConvergeConfig> read_config_file(const fs::path& path) {
    check_input_file(path, "configuration file");
    std::ifstream in(path);
    if (!in) throw InputError({path.string(), 0, 0}, "cannot read the configuration file");
    std::vector<ConvergeConfig> out;
    std::string line;
    for (int n = 1; std::getline(in, line); ++n) {
        if (auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
        if (trim(line).empty()) continue;
        const std::string where = fmt::format("{}:{}", path.string(), n);
        if (line.find(':') == std::string::npos)
            throw InputError({path.string(), n, 1}, "expected 'NAME: K=V K=V ...'");
        out.push_back(parse_config_spec(line, where));
    }
    if (out.empty()) throw InputError({path.string(), 0, 0}, "no configurations in the file");
    return out;
}

std::vector<ConvergeConfig> sweep_configs(const std::string& spec) {
    const std::string what = fmt::format("--sweep '{}'", spec);
    const auto eq = spec.find('=');
    const std::string name(trim(std::string_view(spec).substr(0, eq == std::string::npos ? 0 : eq)));
    if (eq == std::string::npos || !valid_define_name(name))
        throw InputError({}, fmt::format("{}: expected NAME=V1,V2,...", what));
    std::vector<ConvergeConfig> out;
    for (const auto& v : split_list(std::string_view(spec).substr(eq + 1)))
        out.push_back({name + "=" + v, {{name, v}}});
    if (out.empty()) throw InputError({}, fmt::format("{}: no values", what));
    return out;
}

std::vector<double> parse_number_list(const std::string& text, const std::string& option) {
    std::vector<double> out;
    for (const auto& piece : split_list(text)) {
        auto v = parse_double(piece);
        if (!v || !std::isfinite(*v) || *v < 0)
            throw InputError({}, fmt::format("{} '{}': '{}' is not a non-negative number", option, text, piece));
        out.push_back(*v);
    }
    if (out.empty()) throw InputError({}, fmt::format("{} '{}': no values", option, text));
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
}

// ----------------------------------------------------------------------------------------------------- CSV

std::string csv_escape(const std::string& field) {
    if (field.find_first_of(",\"\n\r") == std::string::npos) return field;
    std::string s = "\"";
    for (char c : field) s += c == '"' ? std::string("\"\"") : std::string(1, c);
    return s + "\"";
}

std::vector<std::string> csv_split(const std::string& line, const std::string& where) {
    std::vector<std::string> out(1);
    bool quoted = false;
    for (std::size_t i = 0; i < line.size(); ++i) {
        const char c = line[i];
        if (quoted) {
            if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
                out.back() += '"';
                ++i;
            } else if (c == '"') {
                quoted = false;
            } else {
                out.back() += c;
            }
        } else if (c == '"') {
            quoted = true;
        } else if (c == ',') {
            out.emplace_back();
        } else if (c != '\r') {
            out.back() += c;
        }
    }
    if (quoted) throw InputError({}, fmt::format("{}: unterminated quoted field", where));
    return out;
}

namespace {

using Row = std::vector<std::string>;

const std::vector<std::string> CommonColumns = {"config",  "run",  "seed", "trigger", "target",
                                                "seconds", "work", "unit", "sim_time"};
const std::vector<std::string> ImageColumns = {"mse", "rmse", "rel_mse", "l1", "rel_l1", "max_abs", "ssim"};
const std::vector<std::string> FieldColumns = {"field", "region", "rmse", "rel_l2", "max_abs", "l1", "cells"};

std::string join_row(const Row& r) {
    std::string s;
    for (std::size_t i = 0; i < r.size(); ++i) {
        if (i) s += ',';
        s += csv_escape(r[i]);
    }
    return s;
}

std::string num(double v) { return fmt::format("{:.9g}", v); }

/// A table: header + rows, read from and written to a CSV file.
struct Table {
    std::vector<std::string> header;
    std::vector<Row> rows;

    /// Load `path` if it exists; its header must equal `expected` when given.
    static Table load(const fs::path& path) {
        Table t;
        std::ifstream in(path, std::ios::binary);
        if (!in) return t;
        std::string line;
        for (int n = 1; std::getline(in, line); ++n) {
            if (line.empty() || line == "\r") continue;
            Row r = csv_split(line, fmt::format("{}:{}", path.string(), n));
            if (t.header.empty()) {
                t.header = r;
            } else if (r.size() != t.header.size()) {
                throw InputError({path.string(), n, 1},
                                 fmt::format("{} fields where the header has {} (a damaged file? remove it or "
                                             "choose another --output)",
                                             r.size(), t.header.size()));
            } else {
                t.rows.push_back(std::move(r));
            }
        }
        return t;
    }
    std::string text() const {
        std::string s = join_row(header) + "\n";
        for (const auto& r : rows) s += join_row(r) + "\n";
        return s;
    }
};

std::string safe_name(const std::string& s) {
    std::string out;
    for (char c : s) out += std::isalnum((unsigned char)c) || c == '.' || c == '-' || c == '=' || c == '_' ? c : '_';
    return out.empty() ? "_" : out;
}

/// Study-wide settings lines (everything the rows depend on except the configurations and the run count).
std::vector<std::string> settings_lines(const ConvergeOptions& o, const std::string& kind_columns) {
    std::vector<std::string> s;
    s.push_back("scene: " + fs::absolute(o.scene).lexically_normal().string());
    std::string defs;
    for (const auto& [k, v] : o.defines) defs += fmt::format("{}{}={}", defs.empty() ? "" : ";", k, v);
    s.push_back("defines: " + defs);
    s.push_back("seed: " + std::to_string(o.seed));
    auto list = [](const auto& v) {
        std::string t;
        for (const auto& x : v) t += fmt::format("{}{}", t.empty() ? "" : ",", x);
        return t;
    };
    if (!o.seconds.empty()) s.push_back("checkpoints: seconds " + list(o.seconds));
    if (!o.spp.empty()) s.push_back("checkpoints: spp " + list(o.spp));
    if (!o.steps.empty()) s.push_back("checkpoints: steps " + list(o.steps));
    if (!o.sim_times.empty()) s.push_back("checkpoints: sim_time " + list(o.sim_times));
    s.push_back("reference: " + (o.reference.empty() ? std::string("exact solution")
                                                     : fs::absolute(o.reference).lexically_normal().string()));
    s.push_back("fields: " + list(o.fields));
    s.push_back("region: " + o.region.to_string());
    s.push_back("window: " + (o.window ? list(*o.window) : std::string("all")));
    s.push_back(fmt::format("epsilon: {:g}", o.epsilon));
    s.push_back("columns: " + kind_columns);
    return s;
}

struct RunKey {
    std::string config;
    int run = 0;
    bool operator<(const RunKey& o) const { return std::tie(config, run) < std::tie(o.config, o.run); }
};

/// What a study compares against: a render's reference image, or a simulation's reference field (a reference run's
/// EXR) or exact solution.
class Reference {
public:
    explicit Reference(const ConvergeOptions& o) : m_o(o) {}

    /// Reads ConvergeOptions::reference, if given.
    void load() {
        if (m_o.reference.empty()) return;
        if (std::string why = input_file_problem(m_o.reference, "reference image"); !why.empty())
            throw InputError({}, "--reference: " + why);
        try {
            m_reference = read_image(m_o.reference);
        } catch (const Error& e) {
            throw InputError({m_o.reference.string(), 0, 0}, fmt::format("cannot read the reference: {}", e.what()));
        }
    }
    const Bitmap& image() const { return m_reference; }

    /// Image errors of a render at a checkpoint (the window, if any, cut from both).
    ImageErrors image_errors(const Bitmap& img) const {
        if (img.width() != m_reference.width() || img.height() != m_reference.height())
            throw InputError({m_o.reference.string(), 0, 0},
                             fmt::format("the reference is {}x{} but the render is {}x{}", m_reference.width(),
                                         m_reference.height(), img.width(), img.height()));
        ImageMetricOptions mo;
        mo.epsilon = m_o.epsilon;
        auto crop = [&](const Bitmap& b) {
            if (!m_o.window) return b;
            const auto& w = *m_o.window;
            if (w[2] > b.width() || w[3] > b.height())
                throw InputError({}, fmt::format("--window {},{},{},{} exceeds the {}x{} image", w[0], w[1], w[2], w[3],
                                                 b.width(), b.height()));
            Bitmap c(w[2] - w[0], w[3] - w[1], b.channels());
            for (int y = w[1]; y < w[3]; ++y)
                for (int x = w[0]; x < w[2]; ++x)
                    for (int k = 0; k < b.channel_count(); ++k) c.at(x - w[0], y - w[1], k) = b.at(x, y, k);
            return c;
        };
        try {
            return kelvin::image_errors(crop(img), crop(m_reference), mo);
        } catch (const InputError& e) {
            throw InputError({m_o.reference.string(), 0, 0}, e.bare_message());
        }
    }

    /// Reference values of `field` at the checkpoint's cells (row 0 at min.y).
    std::vector<double> field(const Checkpoint& cp, const std::string& field) const {
        const CellGrid2& g = cp.grid;
        if (!m_o.reference.empty()) {
            const int c = m_reference.channel_index(field);
            if (c < 0)
                throw InputError({m_o.reference.string(), 0, 0},
                                 fmt::format("the reference has no '{}' channel", field));
            const int w = m_reference.width(), h = m_reference.height();
            std::vector<double> v(g.cell_count());
            if (w == g.nx && h == g.ny) {  // the same grid: the values themselves (image rows run top down)
                for (int j = 0; j < g.ny; ++j)
                    for (int i = 0; i < g.nx; ++i) v[std::size_t(j) * g.nx + i] = m_reference.at(i, h - 1 - j, c);
                return v;
            }
            // Another resolution over the same box: bilinear between the reference's cell centres (clamped to
            // the outermost centres), at this grid's cell centres.
            auto ref = [&](int i, int j) {  // j counts up from min.y
                return double(m_reference.at(std::clamp(i, 0, w - 1), h - 1 - std::clamp(j, 0, h - 1), c));
            };
            for (int j = 0; j < g.ny; ++j)
                for (int i = 0; i < g.nx; ++i) {
                    const Vec2d p = g.cell_center(i, j);
                    const double x = (p.x - g.min.x) / (g.max.x - g.min.x) * w - 0.5;
                    const double y = (p.y - g.min.y) / (g.max.y - g.min.y) * h - 0.5;
                    const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
                    const double fx = std::clamp(x - x0, 0.0, 1.0), fy = std::clamp(y - y0, 0.0, 1.0);
                    v[std::size_t(j) * g.nx + i] = (1 - fy) * ((1 - fx) * ref(x0, y0) + fx * ref(x0 + 1, y0)) +
                                                   fy * ((1 - fx) * ref(x0, y0 + 1) + fx * ref(x0 + 1, y0 + 1));
                }
            return v;
        }
        if (!cp.exact)
            throw InputError({m_o.scene.string(), 0, 0},
                             "the simulation knows no exact solution; give --reference (a reference run's EXR)");
        std::vector<double> v(g.cell_count());
        for (int j = 0; j < g.ny; ++j)
            for (int i = 0; i < g.nx; ++i) {
                auto e = cp.exact(field, cp.sim_time, g.cell_center(i, j));
                if (!e)
                    throw InputError({m_o.scene.string(), 0, 0},
                                     fmt::format("the initial condition has no exact solution for '{}' (Taylor–Green "
                                                 "and Lamb–Oseen do); give --reference",
                                                 field));
                v[std::size_t(j) * g.nx + i] = *e;
            }
        return v;
    }

private:
    const ConvergeOptions& m_o;
    Bitmap m_reference;
};

/// What one (configuration, run) pair produced: its rows, or why it has none.
struct RunOutcome {
    bool interrupted = false;
    int error = 0;  ///< 1: InputError, 2: another error (distributed studies carry errors to rank 0)
    std::string message;
    std::string config;
    int run = 0;
    std::size_t fired = 0;
    double work = 0, seconds = 0;
    std::string work_unit;
    std::vector<Row> rows, stats;
};

/// The study's files: convergence.csv (a row per checkpoint, and field), convergence_stats.csv (a row per counter of a
/// run) and convergence.settings (what the rows depend on; a resumed study must match it). Read by every rank,
/// written by rank 0.
class StudyFiles {
public:
    StudyFiles(const ConvergeOptions& o) : m_o(o) {}

    /// The existing study in ConvergeOptions::output_dir, if any (InputError if it cannot be resumed).
    void load(bool simulation) {
        m_simulation = simulation;
        m_csv_path = m_o.output_dir / "convergence.csv";
        m_stats_path = m_o.output_dir / "convergence_stats.csv";
        m_settings_path = m_o.output_dir / "convergence.settings";
        load_existing();
    }
    bool done(const std::string& config, int run) const { return m_done.count({config, run}) > 0; }
    void write_settings() const {
        std::string s =
            "# kelvin converge: the rows of convergence.csv depend on these settings; a resumed study "
            "must match them\n";
        for (const auto& l : settings_lines(m_o, kind_columns())) s += l + "\n";
        std::map<std::string, std::string> configs = m_known_configs;
        for (const auto& c : m_o.configs) configs[c.name] = c.defines_string();
        for (const auto& [name, defs] : configs) s += "config " + name + ": " + defs + "\n";
        write_text_atomically(m_settings_path, s);
    }

    /// Adds a finished run's rows (the caller writes the files); `rank` ran it.
    void add(const RunOutcome& o, std::size_t rank, const Communicator& comm) {
        for (const auto& row : o.rows) m_table.rows.push_back(row);
        for (const auto& row : o.stats) m_stats.rows.push_back(row);
        sort_rows(m_table);
        sort_rows(m_stats);
        m_done.insert({o.config, o.run});
        if (!m_o.quiet && comm.root())
            log_info("converge: {} run {}: {} checkpoint(s), {:.3g} {} in {:.3f} s{}", o.config, o.run, o.fired, o.work,
                     o.work_unit, o.seconds, comm.distributed() ? fmt::format(" (rank {})", rank) : "");
    }

    void write() const {
        write_text_atomically(m_stats_path, m_stats.text());
        write_text_atomically(m_csv_path, m_table.text());  // last: a run is finished once its rows are here
    }
    std::size_t rows() const { return m_table.rows.size(); }
    const fs::path& csv_path() const { return m_csv_path; }
    const fs::path& stats_path() const { return m_stats_path; }

private:
    std::string kind_columns() const {
        // The metric columns depend on the kind of job (validate() found it in the scene).
        return m_simulation ? "field" : "image";
    }

    std::vector<std::string> header() const {
        std::vector<std::string> h = CommonColumns;
        const auto& m = m_simulation ? FieldColumns : ImageColumns;
        h.insert(h.end(), m.begin(), m.end());
        h.push_back("image");
        return h;
    }

    void load_existing() {
        m_table = Table::load(m_csv_path);
        m_stats = Table::load(m_stats_path);
        if (m_stats.header.empty()) m_stats = {{"config", "run", "seed", "counter", "value", "unit"}, {}};
        if (m_table.header.empty()) {
            m_table = {header(), {}};
            m_stats.rows.clear();
            return;
        }
        if (m_table.header != header())
            throw InputError({m_csv_path.string(), 1, 1},
                             "the existing CSV has other columns than this study writes; choose another --output "
                             "or remove it");
        // The settings must match (configurations may be added; an existing one may not change).
        std::ifstream in(m_settings_path);
        if (!in)
            throw InputError({m_settings_path.string(), 0, 0},
                             "missing: cannot resume the study in this directory (choose another --output or remove "
                             "convergence.csv)");
        const auto want = settings_lines(m_o, kind_columns());
        std::set<std::string> want_set(want.begin(), want.end());
        std::string line;
        std::size_t seen = 0;
        for (int n = 1; std::getline(in, line); ++n) {
            if (line.empty() || line[0] == '#') continue;
            if (line.rfind("config ", 0) == 0) {
                const auto colon = line.find(": ");
                const std::string name = line.substr(7, colon == std::string::npos ? std::string::npos : colon - 7);
                const std::string defs = colon == std::string::npos ? "" : line.substr(colon + 2);
                m_known_configs[name] = defs;
                for (const auto& c : m_o.configs)
                    if (c.name == name && c.defines_string() != defs)
                        throw InputError({m_settings_path.string(), n, 1},
                                         fmt::format("configuration '{}' was run with '{}', now given '{}'; rename it "
                                                     "or choose another --output",
                                                     name, defs, c.defines_string()));
                continue;
            }
            if (!want_set.count(line)) {
                const std::string key = line.substr(0, line.find(':'));
                std::string now;
                for (const auto& w : want)
                    if (w.rfind(key + ":", 0) == 0) now = w;
                throw InputError({m_settings_path.string(), n, 1},
                                 fmt::format("the study in this directory was run with '{}', this one has '{}'; choose "
                                             "another --output to start a new study",
                                             line, now.empty() ? "(nothing)" : now));
            }
            ++seen;
        }
        if (seen != want.size())
            throw InputError({m_settings_path.string(), 0, 0},
                             "incomplete settings: cannot resume (choose another --output or remove the directory)");
        for (const auto& r : m_table.rows) {
            auto run = parse_int(r[1]);
            if (!run) throw InputError({m_csv_path.string(), 0, 0}, fmt::format("bad run number '{}'", r[1]));
            m_done.insert({r[0], int(*run)});
        }
        // Counters of runs whose rows never made it into the CSV (cut off in between) are dropped.
        std::erase_if(m_stats.rows, [&](const Row& r) {
            return r.size() < 2 || !m_done.count({r[0], int(parse_int(r[1]).value_or(-1))});
        });
        if (!m_done.empty())
            log_info("converge: resuming {}: {} finished run(s) kept", m_csv_path.string(), m_done.size());
    }

    /// Rows in canonical order: configurations as given (unknown ones after, by name), runs, checkpoints.
    void sort_rows(Table& t) const {
        std::map<std::string, std::size_t> order;
        for (std::size_t i = 0; i < m_o.configs.size(); ++i) order[m_o.configs[i].name] = i;
        auto key = [&](const Row& r) {
            auto it = order.find(r[0]);
            return std::make_tuple(it == order.end() ? order.size() : it->second, it == order.end() ? r[0] : "",
                                   parse_int(r[1]).value_or(0));
        };
        std::stable_sort(t.rows.begin(), t.rows.end(), [&](const Row& a, const Row& b) { return key(a) < key(b); });
    }

    const ConvergeOptions& m_o;
    bool m_simulation = false;
    fs::path m_csv_path, m_stats_path, m_settings_path;
    Table m_table, m_stats;
    std::set<RunKey> m_done;
    std::map<std::string, std::string> m_known_configs;
};

/// Running a study: every rank validates the options and reads the existing files, then the pending runs are
/// spread over the ranks in rounds (one run per rank), and rank 0 records each round in study order.
class Study {
public:
    explicit Study(const ConvergeOptions& o)
        : m_o(o), m_comm(o.comm ? *o.comm : local_communicator()), m_reference(o), m_files(o) {}

    ConvergeSummary run() {
        // Every rank validates and reads the existing study (read only); they agree on errors before any rank
        // writes or runs anything (core/distributed.h).
        run_agreeing(m_comm, [&] {
            validate();
            m_files.load(m_simulation);
        });
        if (m_comm.root()) {
            fs::create_directories(m_o.output_dir);
            m_files.write_settings();
            // The reference next to the checkpoint images, for the plots' image grid (a simulation's reference run
            // has the colour-mapped field in R, G, B).
            if (m_o.images != ConvergeOptions::Images::None && m_reference.image().channel_index("R") == 0 &&
                m_reference.image().channel_count() >= 3) {
                fs::create_directories(m_o.output_dir / "images");
                write_image(m_o.output_dir / "images" / "reference.png", m_reference.image());
            }
        }

        ConvergeSummary summary;
        summary.csv = m_files.csv_path();
        summary.stats_csv = m_files.stats_path();
        const int total = m_o.runs * int(m_o.configs.size());
        // Run-major: every configuration's run 0 first, so a cut-off study has something for each.
        struct Pending {
            const ConvergeConfig* config;
            int run, index;
        };
        std::vector<Pending> pending;
        int index = 0;
        for (int r = 0; r < m_o.runs; ++r)
            for (const auto& config : m_o.configs) {
                ++index;
                if (m_files.done(config.name, r))
                    ++summary.runs_skipped;
                else
                    pending.push_back({&config, r, index});
            }
        // Rounds of one run per rank (one process: one run per round); rank 0 records a round's runs in study
        // order, so the CSV is the one a single process writes, and a cut-off study keeps every finished round.
        const std::size_t ranks = std::size_t(m_comm.size());
        for (std::size_t first = 0; first < pending.size() && !summary.interrupted; first += ranks) {
            RunOutcome mine;
            if (const std::size_t k = first + std::size_t(m_comm.rank()); k < pending.size()) {
                const Pending& p = pending[k];
                if (m_o.cancel.stop_requested()) {
                    mine.interrupted = true;
                } else if (!m_comm.distributed()) {
                    mine = run_one(*p.config, p.run, p.index, total);
                } else {
                    // An error in one rank's run must not leave the others waiting: it travels with the outcome.
                    try {
                        mine = run_one(*p.config, p.run, p.index, total);
                    } catch (const InputError& e) {
                        mine.error = 1, mine.message = e.what();
                    } catch (const std::exception& e) {
                        mine.error = 2, mine.message = e.what();
                    }
                }
            }
            const std::vector<RunOutcome> round = exchange(mine);
            for (std::size_t i = 0; i < round.size(); ++i) {
                const RunOutcome& o = round[i];
                if (o.error) {
                    const std::string m = (i == 0 ? "" : fmt::format("rank {}: ", i)) + o.message;
                    if (o.error == 1) throw InputError({}, m);
                    throw RuntimeError(m);
                }
            }
            for (std::size_t i = 0; i < round.size(); ++i) {
                if (round[i].interrupted) {
                    summary.interrupted = true;
                    continue;
                }
                if (first + i >= pending.size()) continue;
                m_files.add(round[i], i, m_comm);
                ++summary.runs_done;
            }
            if (m_comm.root() && summary.runs_done > 0) m_files.write();
        }
        summary.rows = m_files.rows();
        return summary;
    }

private:
    void validate() {
        const ConvergeOptions& o = m_o;
        if (o.scene.empty()) throw InputError({}, "converge: no scene given");
        if (!fs::is_regular_file(o.scene)) throw InputError({o.scene.string(), 0, 0}, "no such scene file");
        if (o.configs.empty())
            throw InputError({}, "converge: no configuration (give --config NAME:K=V,..., --config-file or --sweep)");
        std::set<std::string> names;
        for (const auto& c : o.configs)
            if (!names.insert(c.name).second)
                throw InputError({}, fmt::format("converge: configuration '{}' is given twice", c.name));
        if (o.runs < 1) throw InputError({}, "converge: --runs must be at least 1");
        const int kinds = !o.seconds.empty() + !o.spp.empty() + !o.steps.empty() + !o.sim_times.empty();
        if (kinds == 0)
            throw InputError({},
                             "converge: no checkpoints (give --checkpoints SECONDS, --spp N,... for renders, or "
                             "--steps / --times for simulations)");
        if (kinds > 1)
            throw InputError({}, "converge: give one kind of checkpoints (--checkpoints, --spp, --steps or --times)");
        for (double s : o.seconds)
            if (!(s > 0)) throw InputError({}, "converge: --checkpoints: times must be positive");
        for (long long s : o.spp)
            if (s < 1) throw InputError({}, "converge: --spp: sample counts must be at least 1");
        for (long long s : o.steps)
            if (s < 0) throw InputError({}, "converge: --steps: step counts must be non-negative");
        if (o.fields.empty()) throw InputError({}, "converge: no --field to compare");
        // 2D: vorticity, u, v; 3D also the vectors' components and the velocity vector (checked against the
        // simulation's own fields when it runs).
        const std::vector<std::string> known = {"vorticity", "u",           "v",           "w",
                                                "velocity",  "vorticity_x", "vorticity_y", "vorticity_z"};
        for (const auto& f : o.fields)
            if (std::find(known.begin(), known.end(), f) == known.end())
                throw InputError({}, fmt::format("converge: --field '{}': expected vorticity, u or v (3D also w, "
                                                 "velocity, vorticity_x, vorticity_y, vorticity_z){}",
                                                 f, did_you_mean(f, known)));
        if (!(o.epsilon > 0)) throw InputError({}, "converge: --epsilon must be positive");
        if (o.window && ((*o.window)[2] <= (*o.window)[0] || (*o.window)[3] <= (*o.window)[1] || (*o.window)[0] < 0 ||
                         (*o.window)[1] < 0))
            throw InputError({}, "converge: --window x0,y0,x1,y1 needs 0 <= x0 < x1 and 0 <= y0 < y1");
        if (o.output_dir.empty()) throw InputError({}, "converge: no output directory");
        if (fs::exists(o.output_dir) && !fs::is_directory(o.output_dir))
            throw InputError({}, fmt::format("-o '{}' exists and is not a directory", o.output_dir.string()));
        // Before any run: a study that cannot write its CSV would throw its work away.
        if (std::string why = output_dir_problem(o.output_dir); !why.empty())
            throw InputError({}, fmt::format("-o '{}': {}", o.output_dir.string(), why));

        m_reference.load();
        // Every configuration must parse, and use every parameter it sets: a misspelt -D would silently run
        // the same configuration twice. The first one tells renders from simulations.
        for (std::size_t i = 0; i < o.configs.size(); ++i) {
            ParsedScene parsed = parse(o.configs[i]);
            bool sim = false;
            for (const auto& child : parsed.root->children)
                sim = sim || (child.node && child.node->kind == "simulation");
            if (i == 0) m_simulation = sim;
            if (sim != m_simulation)
                throw InputError(
                    {o.scene.string(), 0, 0},
                    fmt::format("configuration '{}' runs a {} where '{}' runs a {}", o.configs[i].name,
                                sim ? "simulation" : "render", o.configs[0].name, sim ? "render" : "simulation"));
        }
        if (m_simulation && !o.spp.empty())
            throw InputError({o.scene.string(), 0, 0},
                             "the scene runs a simulation: use --steps, --times or --checkpoints, not --spp (a "
                             "simulation's sample count n_mc is swept as a configuration: --sweep spp=16,64,256 in "
                             "the shipped scenes)");
        if (!m_simulation && (!o.steps.empty() || !o.sim_times.empty()))
            throw InputError({o.scene.string(), 0, 0},
                             "the scene renders: use --spp or --checkpoints, not --steps or --times");
        if (!m_simulation && o.reference.empty())
            throw InputError({o.scene.string(), 0, 0},
                             "the scene renders: give a --reference image (e.g. a long "
                             "render: kelvin scene.xml --spp 4096 -o ref.exr)");
        if (!m_simulation && m_reference.image().channel_index("R") < 0)
            throw InputError({o.reference.string(), 0, 0}, "the reference image has no R, G, B channels");
    }

    ParsedScene parse(const ConvergeConfig& c) const {
        ParseOptions popts;
        popts.defines = m_o.defines;
        for (const auto& [k, v] : c.defines) popts.defines[k] = v;
        ParsedScene parsed = parse_scene_file(m_o.scene, popts);
        for (const auto& d : parsed.unused_defines)
            throw InputError({m_o.scene.string(), 0, 0},
                             fmt::format("configuration '{}': the scene does not use the parameter '{}' (it has no "
                                         "<default name=\"{}\"> or $ reference)",
                                         c.name, d, d));
        return parsed;
    }

    static std::string trigger_name(Checkpoint::Trigger t) {
        switch (t) {
            case Checkpoint::Trigger::Seconds:
                return "seconds";
            case Checkpoint::Trigger::Work:
                return "work";
            case Checkpoint::Trigger::SimTime:
                return "sim_time";
        }
        return "?";
    }
    static std::string label(const Checkpoint& cp) {
        switch (cp.trigger) {
            case Checkpoint::Trigger::Seconds:
                return fmt::format("t{:g}s", cp.target);
            case Checkpoint::Trigger::Work:
                return fmt::format("{}{:g}", cp.work_unit, cp.target);
            case Checkpoint::Trigger::SimTime:
                return fmt::format("simt{:g}", cp.target);
        }
        return "cp";
    }

    /// Every rank's outcome of a round, in rank order, on every rank.
    std::vector<RunOutcome> exchange(const RunOutcome& mine) {
        if (!m_comm.distributed()) return {mine};
        // Serialised as CSV records, one per line: a header record, then the rows, then the counters. (An error
        // message is one line; a line break in it would split the record, so it becomes a space.)
        std::string message = mine.message;
        std::replace(message.begin(), message.end(), '\n', ' ');
        std::string text =
            join_row({mine.interrupted ? "1" : "0", std::to_string(mine.error), message, mine.config,
                      std::to_string(mine.run), std::to_string(mine.fired), num(mine.work), num(mine.seconds),
                      mine.work_unit, std::to_string(mine.rows.size()), std::to_string(mine.stats.size())}) +
            "\n";
        for (const auto* rows : {&mine.rows, &mine.stats})
            for (const Row& r : *rows) text += join_row(r) + "\n";
        std::vector<std::size_t> offsets;
        const std::vector<char> all = m_comm.allgather(text.data(), text.size(), &offsets);
        std::vector<RunOutcome> out(std::size_t(m_comm.size()));
        for (std::size_t r = 0; r < out.size(); ++r) {
            std::istringstream in(std::string(all.data() + offsets[r], all.data() + offsets[r + 1]));
            std::string line;
            std::getline(in, line);
            const Row h = csv_split(line, "a rank's outcome");
            RunOutcome& o = out[r];
            o.interrupted = h.at(0) == "1";
            o.error = int(parse_int(h.at(1)).value_or(2));
            o.message = h.at(2);
            o.config = h.at(3);
            o.run = int(parse_int(h.at(4)).value_or(0));
            o.fired = std::size_t(parse_int(h.at(5)).value_or(0));
            o.work = std::stod(h.at(6));
            o.seconds = std::stod(h.at(7));
            o.work_unit = h.at(8);
            const auto nrows = std::size_t(parse_int(h.at(9)).value_or(0)),
                       nstats = std::size_t(parse_int(h.at(10)).value_or(0));
            for (std::size_t i = 0; i < nrows + nstats && std::getline(in, line); ++i)
                (i < nrows ? o.rows : o.stats).push_back(csv_split(line, "a rank's outcome"));
        }
        return out;
    }

    /// Sets up the context of run `r` (seed m_o.seed + r): its checkpoints, and the sample count or time limit that
    /// reaches the last one.
    void configure(RunContext& ctx, int r) const {
        ctx.seed = m_o.seed + uint64_t(r);
        ctx.quiet = true;
        ctx.cancel = m_o.cancel;
        if (!m_o.seconds.empty()) {
            ctx.checkpoint_seconds = m_o.seconds;
            ctx.time_limit = m_o.seconds.back();
        }
        if (!m_o.spp.empty()) {
            ctx.checkpoint_work = m_o.spp;
            ctx.spp = *std::max_element(m_o.spp.begin(), m_o.spp.end());
        }
        if (!m_o.steps.empty()) ctx.checkpoint_work = m_o.steps;
        ctx.checkpoint_sim_times = m_o.sim_times;
    }

    /// The CSV rows of one checkpoint of run `r` of `config` (one per compared field for a simulation), reached
    /// after `seconds` of compute; writes its images when `write_images`.
    std::vector<Row> checkpoint_rows(const ConvergeConfig& config, int r, uint64_t seed, const Checkpoint& cp,
                                     double seconds, bool write_images) const {
        const bool sim = cp.sim_time >= 0;
        if (sim != m_simulation)
            throw InputError({m_o.scene.string(), 0, 0},
                             sim ? "the scene runs a simulation: use --steps, --times or --checkpoints (and the "
                                   "exact solution or a reference field), not --spp"
                                 : "the scene renders: use --spp or --checkpoints with a --reference image, not "
                                   "--steps or --times");
        const Row base = {config.name,
                          std::to_string(r),
                          std::to_string(seed),
                          trigger_name(cp.trigger),
                          num(cp.target),
                          fmt::format("{:.6f}", seconds),
                          num(cp.work),
                          cp.work_unit,
                          sim ? num(cp.sim_time) : std::string()};
        std::string image_rel;
        Bitmap img;
        if (write_images || !sim) img = cp.image();
        if (write_images && !img.empty()) {
            const fs::path image_dir = m_o.output_dir / "images" / safe_name(config.name);
            fs::create_directories(image_dir);
            const std::string stem = safe_name(fmt::format("run{}_{}", r, label(cp)));  // "mutations/px8"
            write_image(image_dir / (stem + ".exr"), img);
            write_image(image_dir / (stem + ".png"), img);
            image_rel = (fs::path("images") / safe_name(config.name) / (stem + ".png")).string();
        }
        std::vector<Row> rows;
        if (!sim) {
            const ImageErrors e = m_reference.image_errors(img);
            Row row = base;
            for (double v : {e.mse, e.rmse, e.rel_mse, e.l1, e.rel_l1, e.max_abs, e.ssim}) row.push_back(num(v));
            row.push_back(image_rel);
            rows.push_back(std::move(row));
            return rows;
        }
        for (const auto& f : m_o.fields) {
            std::vector<double> values;
            FieldErrors e;
            if (cp.dimension == 3) {
                e = field_errors3(cp, f);
            } else {
                if (!cp.field || !cp.field(f, values))
                    throw InputError({m_o.scene.string(), 0, 0}, fmt::format("the simulation has no field '{}'", f));
                const std::vector<double> ref = m_reference.field(cp, f);
                e = field_errors(values, ref, cp.grid, m_o.region);
            }
            Row row = base;
            row.push_back(f);
            row.push_back(m_o.region.to_string());
            for (double v : {e.rmse, e.rel_l2, e.max_abs, e.l1}) row.push_back(num(v));
            row.push_back(std::to_string(e.cells));
            row.push_back(image_rel);
            rows.push_back(std::move(row));
        }
        return rows;
    }

    /// A 3D checkpoint's errors for `field` against the exact solution, over every cell: "vorticity" and "velocity"
    /// are vectors (vorticity_x/y/z, u/v/w; vector_field_errors), any other name one component.
    FieldErrors field_errors3(const Checkpoint& cp, const std::string& field) const {
        const SourceLoc where{m_o.scene.string(), 0, 0};
        if (!m_o.reference.empty())
            throw InputError(where, "3D studies compare with the exact solution; --reference takes 2D field images");
        if (m_o.region.use_box || m_o.region.use_disk)
            throw InputError(where, "--window and --disk are 2D regions; a 3D study compares every cell");
        const std::vector<std::string> comps =
            field == "vorticity"  ? std::vector<std::string>{"vorticity_x", "vorticity_y", "vorticity_z"}
            : field == "velocity" ? std::vector<std::string>{"u", "v", "w"}
                                  : std::vector<std::string>{field};
        const CellGrid3& g = cp.grid3;
        const std::size_t n = g.cell_count();
        std::vector<double> values, ref, part;
        for (const std::string& c : comps) {
            if (!cp.field || !cp.field(c, part) || part.size() != n)
                throw InputError(where, fmt::format("the simulation has no field '{}'", c));
            values.insert(values.end(), part.begin(), part.end());
            if (!cp.exact3)
                throw InputError(where, "the simulation knows no exact solution (3D: abc and taylor_green at t = 0)");
            for (int k = 0; k < g.nz; ++k)
                for (int j = 0; j < g.ny; ++j)
                    for (int i = 0; i < g.nx; ++i) {
                        const std::optional<double> e = cp.exact3(c, cp.sim_time, g.cell_center(i, j, k));
                        if (!e)
                            throw InputError(where, fmt::format("the initial condition has no exact solution for "
                                                                "'{}' at t = {:g} (abc has one at every time)",
                                                                c, cp.sim_time));
                        ref.push_back(*e);
                    }
        }
        return vector_field_errors(values, ref, n, int(comps.size()));
    }

    /// Runs one (configuration, run) pair; its rows, or interrupted (nothing to record).
    RunOutcome run_one(const ConvergeConfig& config, int r, int index, int total) {
        const uint64_t seed = m_o.seed + uint64_t(r);
        ParsedScene parsed = parse(config);
        // A stop while loading leaves no scene (parse_scene_file, instantiate: core/loading.h): the run is dropped.
        RunOutcome stopped;
        stopped.interrupted = true;
        if (!parsed.root && interrupt_requested()) return stopped;
        ObjectPtr root = instantiate(parsed, {m_o.allow_unused});
        if (!root && interrupt_requested()) return stopped;
        auto job = std::dynamic_pointer_cast<Job>(root);
        if (!job) throw InputError(parsed.root->loc, "the root <scene> did not produce a runnable job");

        RunContext ctx;
        configure(ctx, r);
        const std::size_t expected =
            std::max({m_o.seconds.size(), m_o.spp.size(), m_o.steps.size(), m_o.sim_times.size()});
        const bool write_images =
            m_o.images == ConvergeOptions::Images::All || (m_o.images == ConvergeOptions::Images::First && r == 0);
        std::vector<Row> rows;
        // The seconds column is the compute time of the whole Job::run so far (its setup, e.g. an MLT bootstrap
        // or building the solver, included: equal time means equal time) without the time spent in this
        // callback. The job's own clock (Checkpoint::seconds) starts at its work loop.
        Timer run_timer;
        double in_callbacks = 0;
        ctx.on_checkpoint = [&](const Checkpoint& cp) {
            const double seconds = run_timer.seconds() - in_callbacks;
            struct AddTime {
                double& total;
                Timer timer;
                ~AddTime() { total += timer.seconds(); }
            } add_time{in_callbacks, {}};
            for (Row& row : checkpoint_rows(config, r, seed, cp, seconds, write_images)) rows.push_back(std::move(row));
        };

        if (!m_o.quiet && m_comm.root())
            log_info("converge: [{}/{}] {} run {} (seed {})", index, total, config.name, r, seed);
        // The job's own information lines (one set per run) would drown the study's; warnings still show.
        const LogLevel level = log_level();
        if (level == LogLevel::Info) set_log_level(LogLevel::Warn);
        RunResult result;
        try {
            run_timer.reset();
            result = job->run(ctx);
        } catch (...) {
            set_log_level(level);
            throw;
        }
        set_log_level(level);
        RunOutcome out;
        if (result.interrupted || m_o.cancel.stop_requested()) {
            out.interrupted = true;
            return out;
        }
        const std::size_t fired = rows.size() / (m_simulation ? m_o.fields.size() : 1);
        if (fired < expected)
            log_warn(
                "converge: {} run {}: {} of {} checkpoints reached before the run ended (the scene's own "
                "length: raise its steps, end time or sample count)",
                config.name, r, fired, expected);

        out.config = config.name;
        out.run = r;
        out.fired = fired;
        out.work = result.work;
        out.work_unit = result.work_unit;
        out.seconds = result.seconds;
        out.rows = std::move(rows);
        for (const auto& c : ctx.stats.counters())
            out.stats.push_back({config.name, std::to_string(r), std::to_string(seed), c.name, num(c.value), c.unit});
        out.stats.push_back(
            {config.name, std::to_string(r), std::to_string(seed), "run.seconds", num(result.seconds), "s"});
        out.stats.push_back(
            {config.name, std::to_string(r), std::to_string(seed), "run.work", num(result.work), result.work_unit});
        return out;
    }

    const ConvergeOptions& m_o;
    Communicator& m_comm;
    bool m_simulation = false;  ///< the scene runs a <simulation> (else it renders)
    Reference m_reference;
    StudyFiles m_files;
};

}  // namespace

ConvergeSummary run_convergence(const ConvergeOptions& opts) { return Study(opts).run(); }

}  // namespace kelvin
