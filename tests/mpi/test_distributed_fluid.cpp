// Distributed fluid steps (issue 21, item 2): `mpirun -np N kelvin fluid.xml` steps the 2D and 3D MCFluid solvers
// with every pass split into slabs of cells per rank, and gives the same bits as one process.
//
// Every test runs the real `kelvin` under the real MPI launcher on localhost (--oversubscribe) and compares what the
// runs wrote: the final fields (-o .exr: vorticity, u, v), every frame's fields (fields_NNNN.exr in 2D with the dye's
// dye_NNNN.exr, fields_NNNN.vdb in 3D: vorticity and velocity of every cell) and the diagnostics CSV (energy,
// enstrophy, evaluations, ...; all but the timing columns), between `kelvin` alone, `mpirun -np 1` and `-np 2`. A
// rank that skipped the exchange of its slab, computed rows it does not own, or summed counters twice would change
// them. The slabs are uneven on purpose (odd row counts). Skipped when this build has no MPI module.
#include "mpi/mpi_support.h"

#include <kelvin/core/vdb.h>

#include <map>
#include <regex>

namespace kelvin::test {
namespace {

class DistributedFluid : public MpiTest {};

// The files directly inside `folder`, by name.
std::map<std::string, fs::path> files_in(const fs::path& folder) {
    std::map<std::string, fs::path> files;
    if (!fs::is_directory(folder)) return files;
    for (const auto& e : fs::directory_iterator(folder))
        if (e.is_regular_file()) files[e.path().filename().string()] = e.path();
    return files;
}

// The same grids in two .vdb frames: every voxel of the active box, bit for bit.
::testing::AssertionResult same_vdb(const fs::path& a, const fs::path& b) {
    for (const char* grid : {"vorticity", "velocity", "vorticity_magnitude"}) {
        const VdbDense x = read_vdb_dense(a, grid, 1e8);
        const VdbDense y = read_vdb_dense(b, grid, 1e8);
        if (x.data.empty()) return ::testing::AssertionFailure() << a << ": grid " << grid << " is empty";
        if (x.data.size() != y.data.size() || x.channels != y.channels ||
            !std::equal(std::begin(x.res), std::end(x.res), std::begin(y.res)) ||
            !std::equal(std::begin(x.bbox_min), std::end(x.bbox_min), std::begin(y.bbox_min)))
            return ::testing::AssertionFailure() << a << " and " << b << ": grid " << grid << " differs in size";
        if (std::memcmp(x.data.data(), y.data.data(), x.data.size() * sizeof(float)) != 0) {
            std::size_t differ = 0;
            for (std::size_t i = 0; i < x.data.size(); ++i) differ += std::memcmp(&x.data[i], &y.data[i], 4) != 0;
            return ::testing::AssertionFailure() << a << " and " << b << ": " << differ << " of " << x.data.size()
                                                 << " values of grid " << grid << " differ";
        }
    }
    return ::testing::AssertionSuccess();
}

// Two diagnostics CSVs with the same rows and values, but for the columns of wall times (seconds, step_seconds,
// biot_savart_evals_per_second: their names contain "second").
::testing::AssertionResult same_csv(const fs::path& a, const fs::path& b) {
    const std::vector<std::string> x = lines_of(read_file(a)), y = lines_of(read_file(b));
    if (x.size() < 2) return ::testing::AssertionFailure() << a << " has no rows";
    if (x.size() != y.size()) return ::testing::AssertionFailure() << a << " and " << b << " differ in rows";
    auto split = [](const std::string& line) {
        std::vector<std::string> cells(1);  // empty cells too (a value not estimated)
        for (char ch : line)
            if (ch == ',')
                cells.emplace_back();
            else
                cells.back() += ch;
        return cells;
    };
    const std::vector<std::string> header = split(x[0]);
    for (std::size_t row = 0; row < x.size(); ++row) {
        const std::vector<std::string> u = split(x[row]), v = split(y[row]);
        if (u.size() != header.size() || v.size() != header.size())
            return ::testing::AssertionFailure() << a << " or " << b << ": row " << row << " has other columns";
        for (std::size_t c = 0; c < header.size(); ++c)
            if (header[c].find("second") == std::string::npos && u[c] != v[c])
                return ::testing::AssertionFailure()
                       << a << " and " << b << ", row " << row << ", " << header[c] << ": " << u[c] << " != " << v[c];
    }
    return ::testing::AssertionSuccess();
}

// One fluid scene run alone, with mpirun -np 1 and with -np 2 (one thread per rank): the final fields, every frame
// written (EXR fields and dye, VDB fields) and the CSV are bit-identical. `frames` is the number of data frames
// (EXR or VDB) each run must write, so that the comparison compares something.
void expect_identical(DistributedFluid& t, const std::string& scene, std::vector<std::string> args,
                      std::size_t frames) {
    const fs::path d = t.dir.path();
    auto with = [&](const std::string& name, std::vector<std::string> extra) {
        std::vector<std::string> a = {Scenes + "fluid/" + scene};
        a.insert(a.end(), args.begin(), args.end());
        a.insert(a.end(), extra.begin(), extra.end());
        a.insert(a.end(), {"-q", "-o", (d / (name + ".exr")).string()});
        return a;
    };
    ProcessResult r = t.alone(with("alone", {}));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = t.mpirun(1, with("np1", {}));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = t.mpirun(2, with("np2", {"-t", "1"}));
    ASSERT_EQ(r.exit_code, 0) << describe(r);

    const std::map<std::string, fs::path> one = files_in(d / "alone");
    std::size_t data = 0;
    for (const auto& [name, path] : one) data += path.extension() == ".exr" || path.extension() == ".vdb";
    ASSERT_EQ(data, frames) << "the runs must write the frames compared";
    for (const char* other : {"np1", "np2"}) {
        SCOPED_TRACE(other);
        EXPECT_TRUE(same_bits(d / "alone.exr", d / (std::string(other) + ".exr")));
        const std::map<std::string, fs::path> files = files_in(d / other);
        ASSERT_EQ(files.size(), one.size()) << "the same files in " << (d / other);
        for (const auto& [name, path] : one) {
            ASSERT_TRUE(files.count(name)) << name;
            const fs::path& q = files.at(name);
            if (path.extension() == ".exr") EXPECT_TRUE(same_bits(path, q));
            if (path.extension() == ".vdb") EXPECT_TRUE(same_vdb(path, q));
            if (path.extension() == ".csv") EXPECT_TRUE(same_csv(path, q));
        }
    }
}

// --- 2D: rows of the cache per rank

TEST_F(DistributedFluid, TaylorGreenIsBitIdentical) {
    // 23 rows: slabs of 11 and 12. RK4 backtraces (3 velocity estimates per cell) and importance sampling.
    expect_identical(*this, "taylor_green.xml", {"-D", "res=23", "-D", "spp=16", "-D", "end=0.2", "-D", "every=2"}, 3);
}

TEST_F(DistributedFluid, ViscousTaylorGreenIsBitIdentical) {
    // Feynman–Kac diffusion: n_d Gaussian displacements per cell from each row's stream.
    expect_identical(*this, "taylor_green_viscous.xml",
                     {"-D", "res=21", "-D", "spp=8", "-D", "nd=2", "-D", "end=0.3", "-D", "every=3"}, 2);
}

TEST_F(DistributedFluid, WalkOnSpheresObstacleAndDyeAreBitIdentical) {
    // The cylinder: Walk-on-Spheres velocities around a solid, departure points pushed out of it, and a dye carried
    // along the backtraces (its own pass over its rows, on the displacements of every rank's rows). 25 x 13 cells.
    expect_identical(*this, "cylinder.xml", {"-D", "res=25", "-D", "spp=4", "-D", "end=0.1", "-D", "every=1"},
                     6);  // fields and dye at steps 0, 1, 2
}

// --- 3D: z slabs of the cache per rank

TEST_F(DistributedFluid, VortexRingIsBitIdentical) {
    // Viscous, with stretching (on the gathered velocity): 13 z slabs split 6 / 7.
    expect_identical(*this, "vortex_ring.xml",
                     {"-D", "res=13", "-D", "spp=8", "-D", "nu=0.01", "-D", "end=0.3", "-D", "every=1"}, 4);
}

TEST_F(DistributedFluid, ControlVariatesAreBitIdentical) {
    // Control variates (leapfrogging rings): the previous state's vorticity and velocity, blended with a direct
    // estimate, are kept whole on every rank.
    expect_identical(*this, "leapfrog.xml",
                     {"-D", "res=11", "-D", "spp=4", "-D", "cv=true", "-D", "initial=32", "-D", "blend=0.5", "-D",
                      "end=0.3", "-D", "every=1"},
                     4);
}

// --- the comparison can fail

TEST_F(DistributedFluid, ComparisonSeesADifferentSeed) {
    const fs::path a = dir.path() / "a.exr", b = dir.path() / "b.exr";
    const std::vector<std::string> scene = {
        Scenes + "fluid/taylor_green.xml", "-D", "res=16", "-D", "spp=8", "-D", "end=0.1", "-D", "every=0", "-q"};
    auto with = [&](std::vector<std::string> extra) {
        std::vector<std::string> x = scene;
        x.insert(x.end(), extra.begin(), extra.end());
        return x;
    };
    ProcessResult r = alone(with({"-o", a.string()}));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = mpirun(2, with({"--seed", "1", "-o", b.string()}));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_FALSE(same_bits(a, b));
}

// --- behaving as one process

TEST_F(DistributedFluid, OnlyRankZeroWrites) {
    // Each rank runs in a folder of its own (a wrapper changes to r$OMPI_COMM_WORLD_RANK) with a relative -o: a file
    // written by rank 1 would land in r1/. Rank 0 writes the final fields, the CSV, the frames and the montage, and
    // says so once per file.
    for (const char* r : {"r0", "r1"}) fs::create_directory(dir.path() / r);
    const fs::path wrapper = dir.path() / "per_rank.sh";
    write_file(wrapper, "#!/bin/sh\ncd \"" + dir.path().string() + "/r$OMPI_COMM_WORLD_RANK\" && exec \"$@\"\n");
    fs::permissions(wrapper, fs::perms::owner_all);
    const ProcessResult r = run_process(
        Mpiexec,
        {"-np", "2", "--oversubscribe", "--quiet", wrapper.string(), KELVIN_CLI, Scenes + "fluid/taylor_green.xml",
         "-D", "res=16", "-D", "spp=8", "-D", "end=0.1", "-D", "every=1", "-o", "tg.exr"},
        MpiEnv, std::chrono::seconds(60));
    ASSERT_FALSE(r.timed_out) << describe(r);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(count_lines(r.err, "Done: mcfluid"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "on 2 ranks x"), 1u) << r.err;
    EXPECT_TRUE(fs::is_empty(dir.path() / "r1")) << "rank 1 wrote files";
    // tg.exr, diagnostics.csv, montage.png and vorticity and fields at steps 0, 1, 2.
    const std::map<std::string, fs::path> files = files_in(dir.path() / "r0" / "tg");
    EXPECT_EQ(files.size(), 8u);
    EXPECT_TRUE(fs::exists(dir.path() / "r0" / "tg.exr"));
    EXPECT_EQ(count_lines(r.err, "wrote "), files.size() + 1) << r.err;
    for (const auto& [name, path] : files)
        EXPECT_EQ(count_lines(r.err, "wrote tg/" + name), 1u) << name << "\n" << r.err;
}

TEST_F(DistributedFluid, TimeLimitStopsEveryRankAtTheSameStep) {
    // Rank 0's clock decides for everyone: both ranks stop after the same step (a rank left stepping would hang the
    // run in a collective), and the result is written once.
    const fs::path out = dir.path() / "timed.exr";
    const ProcessResult r = mpirun(2,
                                   {Scenes + "fluid/taylor_green.xml", "-D", "res=32", "-D", "spp=16", "-D", "end=1000",
                                    "-D", "every=0", "--time-limit", "1", "-o", out.string()},
                                   60);
    ASSERT_FALSE(r.timed_out) << describe(r);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(count_lines(r.err, "time limit of 1 s reached"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "Done: mcfluid"), 1u) << r.err;
    EXPECT_TRUE(fs::exists(out));
}

TEST_F(DistributedFluid, SignalToOneRankStopsAllAtAStepBoundary) {
    // A signal that reaches one rank only: the others learn it at the end of the pass, every rank keeps the last
    // whole state, and the run ends as interrupted (exit code 130) with that state written once.
    const fs::path out = dir.path() / "one.exr";
    std::vector<std::string> a = {"-np",       "2",        "--oversubscribe",
                                  "--quiet",   KELVIN_CLI, Scenes + "fluid/taylor_green.xml",
                                  "-D",        "res=32",   "-D",
                                  "spp=16",    "-D",       "end=1000",
                                  "-D",        "every=0",  "-o",
                                  out.string()};
    Process p(Mpiexec, a, MpiEnv);
    ASSERT_TRUE(
        p.wait_until([&] { return p.stderr_so_far().find("steps") != std::string::npos; }, std::chrono::seconds(60)))
        << p.stderr_so_far();
    // The ranks are mpirun's children; signal the last started (rank 1, as a rule).
    const ProcessResult ps = run_process("/usr/bin/pgrep", {"-P", std::to_string(p.pid())}, {});
    const std::vector<std::string> pids = lines_of(ps.out);
    ASSERT_FALSE(pids.empty()) << ps.out << ps.err;
    ::kill(std::stoi(pids.back()), SIGTERM);
    ProcessResult r = p.wait(std::chrono::seconds(60));
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_EQ(count_lines(r.err, "Interrupted: mcfluid"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "wrote " + out.string()), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "wrote "), 2u) << r.err;  // and the CSV so far
    ASSERT_TRUE(fs::exists(out)) << r.err;
    const Bitmap img = read_image(out);
    EXPECT_GE(img.channel_index("vorticity"), 0);
}

}  // namespace
}  // namespace kelvin::test
