// Ring cores in the azimuthal mean of omega_theta (include/kelvin/fluid/ring_cores.h): exact Gaussian rings on a
// grid found at their (R, z) and with their circulation, two rings apart, a noisy field, the exact reference's
// meridian grid, and the columns a 3D run's diagnostics.csv gets from them.
#include "common/support.h"

#include <kelvin/core/job.h>
#include <kelvin/core/parser.h>
#include <kelvin/core/properties.h>
#include <kelvin/core/random.h>
#include <kelvin/core/registry.h>
#include <kelvin/fluid/axisymmetric_rings.h>
#include <kelvin/fluid/fields.h>
#include <kelvin/fluid/ring_cores.h>

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using namespace kelvin;
using namespace kelvin::fluid;
namespace fs = std::filesystem;

namespace {

// The vortex_ring plugin's field: rings of radius R about the z axis at axial positions zs.
Vec3d rings_omega(const Vec3d& x, double R, double gamma, double sigma, const std::vector<double>& zs) {
    Vec3d w(0.0);
    const double rho = std::hypot(x.x, x.y);
    if (!(rho > 0)) return w;
    for (double z0 : zs) {
        const double s2 = (rho - R) * (rho - R) + (x.z - z0) * (x.z - z0);
        const double mag = gamma / (Pi * sigma * sigma) * std::exp(-s2 / (sigma * sigma));
        w += mag * Vec3d(-x.y / rho, x.x / rho, 0.0);
    }
    return w;
}

// The leapfrog scene's box and cache (h = 5/48 = 0.104), the rings' vorticity on it, plus Gaussian noise of
// standard deviation `noise` per component and cell.
VectorGrid3 ring_grid(const std::vector<double>& zs, double noise = 0, double sigma = 0.2) {
    const Domain3 box{Vec3d(-2.5, -2.5, -1.5), Vec3d(2.5, 2.5, 3.5), false};
    VectorGrid3 w(box, 48, 48, 48);
    Random rng(7, 0);
    auto normal = [&rng]() {
        const double u1 = std::max(rng.next_double(), 1e-300), u2 = rng.next_double();
        return std::sqrt(-2 * std::log(u1)) * std::cos(2 * Pi * u2);
    };
    for (int k = 0; k < 48; ++k)
        for (int j = 0; j < 48; ++j)
            for (int i = 0; i < 48; ++i) {
                Vec3d v = rings_omega(w.x.cell_center(i, j, k), 1.0, 1.0, sigma, zs);
                if (noise > 0) v += noise * Vec3d(normal(), normal(), normal());
                w.set(w.x.index(i, j, k), v);
            }
    return w;
}

const double H = 5.0 / 48;

}  // namespace

// One exact Gaussian ring (R 1, Gamma 1, sigma 0.2, two cells per core radius), its centre off the bins' centres:
// found at (R, z0) within 0.05 h and with its circulation within 2 %. Measured: r off by 0.02 h, z by 1e-4 h,
// circulation 1.002. Seen to fail without the sub-bin refinement (r off by 0.1 h), with the omega-weighted centroid
// of the 3x3 bins instead of the parabola (r off by 0.075 h), and with e_theta reversed (no core).
TEST(RingCores, FindOneExactRing) {
    const double z0 = 0.37;
    const VectorGrid3 w = ring_grid({z0});
    const std::vector<RingCore> cores = ring_cores(w, Vec3d(0.0), Vec3d(0, 0, 1), 1);
    ASSERT_EQ(cores.size(), 1u);
    std::cout << "[ measured ] core (" << cores[0].r << ", " << cores[0].z << "), circulation " << cores[0].circulation
              << ", errors in h: " << (cores[0].r - 1) / H << ", " << (cores[0].z - z0) / H << "\n";
    EXPECT_NEAR(cores[0].r, 1.0, 0.05 * H);
    EXPECT_NEAR(cores[0].z, z0, 0.05 * H);
    EXPECT_NEAR(cores[0].circulation, 1.0, 0.02);
    EXPECT_GT(cores[0].peak, 0.8 / (Pi * 0.04));  // the peak, a little smoothed by the bins
    // Another origin and a tilted axis: the same ring seen about an axis that is not its own has no such core.
    const std::vector<RingCore> moved = ring_cores(w, Vec3d(0, 0, 1), Vec3d(0, 0, 1), 1);
    ASSERT_EQ(moved.size(), 1u);
    EXPECT_NEAR(moved[0].z, z0 - 1, 0.05 * H);  // z is measured from the origin along the axis
    EXPECT_TRUE(ring_cores(w, Vec3d(0.0), Vec3d(0, 0, -1), 1).empty()) << "omega_theta < 0 about the reversed axis";
}

// The leapfrog scene's two rings, 0.6 apart: two cores sorted by z, each at (R, z_k) within 0.05 h, each with its
// own circulation within 3 % (the bins nearer one core hold 1.7 % of the other ring's Gaussian and lose as much);
// asked for three, still two (no third maximum reaches a quarter of the strongest). The same two rings 0.1 apart
// have merged: one core holding both circulations. Seen to fail with every bin's circulation given to the first
// core (2 and 0), with the cores left in their order of strength, and without the sub-bin refinement (z 0.36 h off,
// circulations 0.94 and 1.06: the split between the cores follows their positions).
TEST(RingCores, FindTwoRingsAndTheirCirculations) {
    const VectorGrid3 w = ring_grid({0.6 + 0.1, 0.1});
    const std::vector<RingCore> cores = ring_cores(w, Vec3d(0.0), Vec3d(0, 0, 1), 3);
    ASSERT_EQ(cores.size(), 2u);
    for (int k = 0; k < 2; ++k) {
        SCOPED_TRACE(k);
        EXPECT_NEAR(cores[k].r, 1.0, 0.05 * H);
        EXPECT_NEAR(cores[k].z, 0.1 + 0.6 * k, 0.05 * H);
        EXPECT_NEAR(cores[k].circulation, 1.0, 0.03);
    }
    // Merged into one (the same two rings 0.1 apart: one maximum between them) gives one core with both circulations.
    const std::vector<RingCore> merged = ring_cores(ring_grid({0.05, -0.05}), Vec3d(0.0), Vec3d(0, 0, 1), 2);
    ASSERT_EQ(merged.size(), 1u);
    EXPECT_NEAR(merged[0].z, 0.0, 0.05 * H);
    EXPECT_NEAR(merged[0].circulation, 2.0, 0.05);
}

// Noise of a quarter of the peak vorticity per component and cell (much more than a 3D mcfluid state's): both cores
// still found within 0.25 h, circulations within 10 % (the azimuthal mean averages ~60 cells per bin; bins below
// three times the noise, from the median |omega_theta|, or not connected to the core through bins above it, are not
// counted, which loses the core's edge). Measured: positions within 0.07 h, circulations 0.97 and 0.92. Seen to fail
// when every positive bin counts (1.61 and 1.69: the noise's positive half over the half plane), when every
// positive bin connected to the core counts (1.10 and 1.59), and when every bin above the floor counts, connected
// or not (1.14 and 1.07: the noisier bins near the axis).
TEST(RingCores, NoisyFieldStillFindsThem) {
    const double peak = 1 / (Pi * 0.04);
    const VectorGrid3 w = ring_grid({0.1, 0.7}, 0.25 * peak);
    const std::vector<RingCore> cores = ring_cores(w, Vec3d(0.0), Vec3d(0, 0, 1), 2);
    ASSERT_EQ(cores.size(), 2u);
    for (int k = 0; k < 2; ++k) {
        SCOPED_TRACE(k);
        std::cout << "[ measured ] noisy core " << k << ": errors in h " << (cores[k].r - 1) / H << ", "
                  << (cores[k].z - 0.1 - 0.6 * k) / H << ", circulation " << cores[k].circulation << "\n";
        EXPECT_NEAR(cores[k].r, 1.0, 0.25 * H);
        EXPECT_NEAR(cores[k].z, 0.1 + 0.6 * k, 0.25 * H);
        EXPECT_NEAR(cores[k].circulation, 1.0, 0.1);
    }
}

// A box far longer than its cells are wide along the axis (a non-cubic cache clamped in cells: 8 x 8 x 8 cells over
// 1e155 along z, what the scene fuzzer made of leapfrog_twice.xml) gets a meridian grid of at most about two bins per
// cell along the box, not one of the cells' width (which asked for 1e155 bins and threw std::length_error); a box
// whose extent overflows (sides of 2e300, from `-D half=1e300`) gets none.
TEST(RingCores, AnElongatedBoxGetsABoundedMeridianGrid) {
    const Domain3 box{Vec3d(-1, -1, -1e155), Vec3d(1, 1, 5), false};
    VectorGrid3 w(box, 8, 8, 8);
    w.fill(Vec3d(1, 0, 0));
    const MeridianGrid g = azimuthal_mean(w, Vec3d(0.0), Vec3d(0, 0, 1), 0.25);
    EXPECT_LE(g.nz, 2 * 8 + 4);
    EXPECT_LE(g.nr, 2 * 8 + 4);
    EXPECT_NO_THROW(ring_cores(w, Vec3d(0.0), Vec3d(0, 0, 1), 2));
    // A box whose corners' distance from the axis overflows (sides of 2e300): no meridian grid, no cores, no throw.
    VectorGrid3 huge(Domain3{Vec3d(-1e300, -1e300, -1), Vec3d(1e300, 1e300, 5), false}, 8, 8, 2);
    huge.fill(Vec3d(1, 0, 0));
    EXPECT_EQ(azimuthal_mean(huge, Vec3d(0.0), Vec3d(0, 0, 1), 2.9).nr, 0);
    EXPECT_TRUE(ring_cores(huge, Vec3d(0.0), Vec3d(0, 0, 1), 2).empty());
}

// The exact reference's own meridian grid (what `ring_reference` writes its core columns from) gives the same cores
// as the solvers' azimuthal mean at t = 0, with the same smoothing (peaks within 5 % of the 3D grid's: measured 0.99
// and 0.96 of them, a bin's value depending on its offset from the core), and after t = 0.5 its two labelled rings
// and the cores found agree: the rear ring has shrunk and the front one grown, the cores within one bin of each
// ring's impulse centroid (sum z r^2 g / sum r^2 g of its own elements, which the two deformed cores' overlap moves
// from the vorticity maximum). The circulations are within 4 %: the two smoothed cores overlap, and the row of bins
// nearest the midway line goes whole to one core (measured 0.966 and 1.034). Seen to fail with the blobs' centre
// off by half a bin (cores 0.5 h off) and with their width the lattice spacing alone (peaks 1.08 and 1.04 of the
// grid's) or h (0.90 and 0.87).
TEST(RingCores, ExactReferenceMeridianAgrees) {
    AxisymmetricRings rings(1, 1, 0.2, {0.1, 0.7}, 4);
    auto cores_of = [&]() { return find_ring_cores(rings.meridian(H, -1, 3, 2.5), 2); };
    std::vector<RingCore> c = cores_of();
    ASSERT_EQ(c.size(), 2u);
    for (int k = 0; k < 2; ++k) {
        EXPECT_NEAR(c[k].r, 1.0, 0.05 * H);
        EXPECT_NEAR(c[k].z, 0.1 + 0.6 * k, 0.05 * H);
        EXPECT_NEAR(c[k].circulation, 1.0, 0.04);
        EXPECT_NEAR(c[0].circulation + c[1].circulation, 2.0, 0.01);
    }
    // The same smoothing as the solvers' binning: the peaks agree with the azimuthal mean of the 3D grid.
    const std::vector<RingCore> grid = ring_cores(ring_grid({0.1, 0.7}), Vec3d(0.0), Vec3d(0, 0, 1), 2);
    ASSERT_EQ(grid.size(), 2u);
    std::cout << "[ measured ] peaks: reference meridian " << c[0].peak << ", " << c[1].peak << "; 3D grid "
              << grid[0].peak << ", " << grid[1].peak << "\n";
    EXPECT_NEAR(c[0].peak / grid[0].peak, 1.0, 0.05);  // measured 0.99 and 0.96 (a bin's value: its offset counts)
    EXPECT_NEAR(c[1].peak / grid[1].peak, 1.0, 0.05);
    for (int s = 0; s < 5; ++s) rings.step(0.1);
    c = cores_of();
    ASSERT_EQ(c.size(), 2u);
    EXPECT_LT(c[0].r, 0.97);  // the rear ring shrinks ...
    EXPECT_GT(c[1].r, 1.03);  // ... and the front one grows
    EXPECT_NEAR(c[0].z, rings.position(0), H);
    EXPECT_NEAR(c[1].z, rings.position(1), H);
    EXPECT_NEAR(c[0].r, rings.radius(0), H);
    EXPECT_NEAR(c[1].r, rings.radius(1), H);
}

namespace {

std::map<std::string, std::vector<std::string>> csv_columns(const fs::path& p) {
    std::ifstream in(p);
    std::string line;
    std::getline(in, line);
    std::vector<std::string> names;
    std::stringstream hs(line);
    for (std::string c; std::getline(hs, c, ',');) names.push_back(c);
    std::map<std::string, std::vector<std::string>> cols;
    while (std::getline(in, line)) {
        std::vector<std::string> f;
        std::size_t start = 0;
        for (std::size_t at; (at = line.find(',', start)) != std::string::npos; start = at + 1)
            f.push_back(line.substr(start, at - start));
        f.push_back(line.substr(start));
        EXPECT_EQ(f.size(), names.size()) << line;
        for (std::size_t c = 0; c < names.size() && c < f.size(); ++c) cols[names[c]].push_back(f[c]);
    }
    return cols;
}

void run_scene(const std::string& scene, const std::map<std::string, std::string>& defines, const fs::path& out) {
    ParseOptions opts;
    opts.defines = defines;
    auto job = std::dynamic_pointer_cast<Job>(
        instantiate(parse_scene_file(fs::path(KELVIN_SOURCE_DIR) / "scenes" / "fluid" / scene, opts)));
    ASSERT_TRUE(job);
    RunContext ctx;
    ctx.quiet = true;
    ctx.output = out;
    job->run(ctx);
}

}  // namespace

// A 3D mcfluid run of the ring scene writes core1_r, core1_z, core1_circulation after the other columns; the core
// starts at (1, 0) and moves forward (measured 0.108 in t = 0.6 at 24^3 and n_mc 16, 0.72 of Saffman's speed: two
// cells per core radius are slow), keeping its radius and most of its circulation; the leapfrog scene gets two
// triples; a field that is not rings gets none. Seen to fail with the cores found at t = 0 only (core1_z constant).
TEST(RingCores, McfluidRunWritesCoreColumns) {
    ktest::TempDir dir;
    run_scene("vortex_ring.xml",
              {{"res", "24"}, {"spp", "16"}, {"end", "0.6"}, {"every", "0"}, {"dt", "0.1"}, {"solver", "mcfluid"}},
              dir / "ring.png");
    auto cols = csv_columns(dir / "ring" / "diagnostics.csv");
    ASSERT_EQ(cols["core1_z"].size(), 7u);
    ASSERT_EQ(cols["core1_r"].size(), 7u);
    ASSERT_EQ(cols["core1_circulation"].size(), 7u);
    const double z0 = std::stod(cols["core1_z"].front()), z1 = std::stod(cols["core1_z"].back());
    std::cout << "[ measured ] mcfluid ring core z " << z0 << " -> " << z1 << ", r " << cols["core1_r"].back()
              << ", circulation " << cols["core1_circulation"].front() << " -> " << cols["core1_circulation"].back()
              << "\n";
    EXPECT_NEAR(z0, 0.0, 0.05);
    EXPECT_GT(z1 - z0, 0.05);
    EXPECT_LT(z1 - z0, 0.6 * 0.249 * 1.1);  // not faster than Saffman's speed
    EXPECT_NEAR(std::stod(cols["core1_r"].back()), 1.0, 0.1);
    EXPECT_GT(std::stod(cols["core1_circulation"].back()), 0.7);

    run_scene("leapfrog.xml", {{"res", "16"}, {"spp", "4"}, {"end", "0.1"}, {"every", "0"}}, dir / "leap.png");
    cols = csv_columns(dir / "leap" / "diagnostics.csv");
    for (const char* c : {"core1_r", "core1_z", "core1_circulation", "core2_r", "core2_z", "core2_circulation"})
        EXPECT_EQ(cols[c].size(), 2u) << c;
    EXPECT_EQ(cols.count("core3_r"), 0u);

    const ObjectPtr abc = Registry::instance().create(Properties("vorticity", "abc"));
    const RingCoreColumns none(dynamic_cast<const VorticityField3*>(abc.get()));
    EXPECT_FALSE(none.active());
    EXPECT_EQ(none.header(), "");
    const ObjectPtr ring = Registry::instance().create(Properties("vorticity", "vortex_ring"));
    EXPECT_EQ(RingCoreColumns(dynamic_cast<const VorticityField3*>(ring.get())).header(),
              ",core1_r,core1_z,core1_circulation");
}

// `ring_reference` (tools/ring_reference.cpp): the header the studies read, a row every --every steps and the last,
// the impulse conserved (to 1e-6), both cores moving forward from their initial (1, 0) and (1, 0.6), each ring's own
// elements at its offset at t = 0; a bad argument is one line naming the option, exit 2. Seen to fail with the rows'
// time off by one step (time = step * dt of the next step).
TEST(RingReference, WritesTheCoreColumnsAndRefusesBadArguments) {
    ktest::TempDir dir;
    const fs::path out = dir / "ref.csv";
    const std::string cmd = std::string("\"") + KELVIN_RING_REFERENCE +
                            "\" --core 0.2 --offsets 0,0.6 --dt 0.05 --end 0.5 --every 4 -o \"" + out.string() + "\"";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ifstream in(out);
    std::string header;
    std::getline(in, header);
    EXPECT_EQ(header,
              "step,time,impulse_z,impulse_centroid_z,core1_r,core1_z,core1_circulation,core2_r,core2_z,"
              "core2_circulation,ring1_r,ring1_z,ring2_r,ring2_z,seconds");
    auto cols = csv_columns(out);
    ASSERT_EQ(cols["step"], (std::vector<std::string>{"0", "4", "8", "10"}));
    EXPECT_DOUBLE_EQ(std::stod(cols["time"][1]), 0.2);
    EXPECT_DOUBLE_EQ(std::stod(cols["time"].back()), 0.5);
    const double p0 = std::stod(cols["impulse_z"].front());
    EXPECT_NEAR(p0, 2 * Pi * (1 + 0.04 / 2), 0.01);  // two rings of impulse pi Gamma (R^2 + sigma^2 / 2)
    EXPECT_NEAR(std::stod(cols["impulse_z"].back()) / p0, 1.0, 1e-6);
    EXPECT_NEAR(std::stod(cols["core1_z"].front()), 0.0, 0.01);
    EXPECT_NEAR(std::stod(cols["core2_z"].front()), 0.6, 0.01);
    EXPECT_NEAR(std::stod(cols["core1_r"].front()), 1.0, 0.01);
    EXPECT_NEAR(std::stod(cols["ring2_z"].front()), 0.6, 1e-9);
    EXPECT_GT(std::stod(cols["core1_z"].back()), 0.15);  // the rear ring, faster, goes 0.2-0.3 in t = 0.5
    EXPECT_GT(std::stod(cols["core2_z"].back()), 0.6 + 0.05);
    EXPECT_LT(std::stod(cols["core1_r"].back()), 1.0);  // the rear ring shrinks

    const fs::path err = dir / "err.txt";
    // Bad arguments, including the ones that would exhaust the memory or never finish: one line, exit 2.
    const std::pair<std::string, std::string> cases[] = {
        {"--core 2", "--core: must be positive and smaller than the radius"},
        {"--spacing 1e-9", "--spacing: must be at least core / 64 (0.003125)"},
        {"--offsets 0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16", "--offsets: at most 16 rings"}};
    for (const auto& [args, message] : cases) {
        const std::string bad =
            std::string("\"") + KELVIN_RING_REFERENCE + "\" " + args + " 2> \"" + err.string() + "\"";
        const int status = std::system(bad.c_str());
        ASSERT_TRUE(WIFEXITED(status));
        EXPECT_EQ(WEXITSTATUS(status), 2) << args;
        std::ifstream e(err);
        std::stringstream text;
        text << e.rdbuf();
        EXPECT_EQ(text.str(), "ring_reference: error: " + message + "\n");
    }
}

namespace {

// The table row of tools/fluid_leapfrog_table.py for a folder holding only reference.csv, split at '|'.
std::vector<std::string> reference_row(const fs::path& dir, double sigma) {
    const fs::path out = dir / "table.md";
    const std::string cmd = std::string("/usr/bin/python3 \"") + KELVIN_SOURCE_DIR +
                            "/tools/fluid_leapfrog_table.py\" \"" + dir.string() + "\" --sigma " +
                            std::to_string(sigma) + " > \"" + out.string() + "\"";
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    std::ifstream in(out);
    for (std::string line; std::getline(in, line);)
        if (line.rfind("| exact", 0) == 0) {
            std::vector<std::string> cells;
            std::stringstream ls(line.substr(1));
            for (std::string c; std::getline(ls, c, '|');) cells.push_back(c.substr(1, c.size() - 2));
            return cells;
        }
    ADD_FAILURE() << "no row for the reference in " << out;
    return {};
}

// ring_reference with `args` into dir/reference.csv, then that folder's table row (reference_row); empty on failure.
std::vector<std::string> exact_row(const fs::path& dir, const std::string& args, double sigma) {
    fs::create_directories(dir);
    const std::string cmd =
        std::string("\"") + KELVIN_RING_REFERENCE + "\" " + args + " -o \"" + (dir / "reference.csv").string() + "\"";
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    return reference_row(dir, sigma);
}

/// The two pass times of a table row's pass column ("t1; t2"), checking that there are exactly two.
void expect_two_passes(const std::vector<std::string>& row, double t1, double t2, double tolerance1,
                       double tolerance2) {
    ASSERT_GE(row.size(), 5u);
    EXPECT_EQ(row[2], "2");
    double a = 0, b = 0;
    ASSERT_EQ(std::sscanf(row[3].c_str(), "%lf; %lf", &a, &b), 2) << row[3];
    EXPECT_NEAR(a, t1, tolerance1);
    EXPECT_NEAR(b, t2, tolerance2);
    EXPECT_EQ(row[4].rfind("-", 0), 0u) << "still two rings: " << row[4];
}

}  // namespace

// The study's pass and merger counts (tools/fluid_leapfrog_table.py) on the exact dynamics from `ring_reference`:
// thin cores (sigma 0.1, 0.6 apart) leapfrog, passing at t of about 1.4 and 4.1 and still two rings at t = 4.5;
// the leapfrog scene's thick cores (sigma 0.2, states every 0.05 as in the study) pass once, at t of about 1.2-1.4,
// and merge by 1.7-2.1 (measured: 1.45 and 4.05; 1.23 and 1.8; about 4 s in all). Seen to fail with a pass counted
// at every change of r order (4 passes of the thin rings: the half-way points too) and without the rule that a
// pass must follow a half-way point (passes at 1.23 and 1.33 of the thick rings, their order flickering as the
// drawn-out rear core goes through).
TEST(RingReference, StudyTableCountsThePasses) {
    if (!fs::exists("/usr/bin/python3")) GTEST_SKIP() << "no /usr/bin/python3";
    ktest::TempDir dir;
    // Columns: solver, runs, passes, pass times, merger t, ...
    expect_two_passes(exact_row(dir / "thin", "--core 0.1 --per-sigma 2 --dt 0.1 --end 4.5 --spacing 0.05", 0.1), 1.4,
                      4.1, 0.15, 0.15);
    const std::vector<std::string> b =
        exact_row(dir / "thick", "--core 0.2 --dt 0.05 --end 2.2 --spacing 0.1041666667", 0.2);
    ASSERT_GE(b.size(), 5u);
    EXPECT_EQ(b[2], "1");
    EXPECT_NEAR(std::stod(b[3]), 1.3, 0.1);
    EXPECT_NEAR(std::stod(b[4]), 1.9, 0.2);
}

// scenes/fluid/leapfrog_twice.xml's rings (R 1.5, sigma 0.2, 1.1 apart) leapfrog twice in the exact dynamics: passes
// at t of about 4.6 and 11 (measured with 3 elements per core radius and steps of 0.1: 4.55 and 11.25; with 4 and
// 0.05, the study's: 4.55 and 10.75), still two rings at t = 12 (about 5 s). It guards the scene's claim: with
// leapfrog.xml's ratio of core to separation (a third: offsets 0,0.66 at this R and core) the same count is one
// pass and a merger.
TEST(RingReference, TheLeapfrogTwiceScenesRingsPassTwice) {
    if (!fs::exists("/usr/bin/python3")) GTEST_SKIP() << "no /usr/bin/python3";
    ktest::TempDir dir;
    expect_two_passes(
        exact_row(dir.path(), "--radius 1.5 --core 0.2 --offsets 0,1.1 --per-sigma 3 --dt 0.1 --end 12 --spacing 0.1",
                  0.2),
        4.6, 11.0, 0.2, 0.4);
}
