// Distributed runs (issue 21, core/distributed.h): `mpirun -np N kelvin ...` gives the same bits as one process.
//
// Every test runs the real `kelvin` under the real MPI launcher on localhost (2 ranks, --oversubscribe), and compares
// the pixels (every channel, bit for bit) with `kelvin` run alone and with `mpirun -np 1`. A merge that summed
// floating-point splats per rank, a rank that rendered tiles it does not own, or passes sized from each rank's own
// clock would all change bits. Skipped when this build has no MPI module.
#include "mpi/mpi_support.h"

#include <regex>

namespace kelvin::test {
namespace {

class Distributed : public MpiTest {};

bool has_light(const fs::path& p) {
    const Bitmap img = read_image(p);
    double sum = 0;
    for (std::size_t i = 0; i < img.size(); ++i) {
        if (!std::isfinite(img.data()[i])) return false;
        sum += img.data()[i];
    }
    return sum > 0;
}

// One scene, rendered alone, with mpirun -np 1 and with -np 2: the three images are bit-identical.
void expect_identical(Distributed& t, const fs::path& dir, const std::string& name, std::vector<std::string> args) {
    const fs::path one = dir / (name + "_alone.exr"), np1 = dir / (name + "_np1.exr"), np2 = dir / (name + "_np2.exr");
    auto with = [&](const fs::path& out) {
        std::vector<std::string> a = args;
        a.insert(a.end(), {"-q", "-o", out.string()});
        return a;
    };
    ProcessResult r = t.alone(with(one));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = t.mpirun(1, with(np1));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = t.mpirun(2, with(np2));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_TRUE(has_light(one)) << "the comparison needs an image with light in it";
    EXPECT_TRUE(same_bits(one, np1));
    EXPECT_TRUE(same_bits(one, np2));
}

// --- the pixel-sampling integrators: tiles owned round-robin, buffers merged exactly

TEST_F(Distributed, PathTracerIsBitIdentical) {
    expect_identical(*this, dir.path(), "path",
                     {Scenes + "render/cornell-box.xml", "-D", "res=40", "--spp", "3", "--seed", "7"});
}

TEST_F(Distributed, LightTracerSplatsAreFoldedInUnitOrder) {
    // ptracer's splats are double sums whose order matters: gathered to rank 0 and folded in unit order.
    expect_identical(*this, dir.path(), "ptracer",
                     {Scenes + "render/cornell-box.xml", "-D", "res=64", "-D", "integrator=ptracer", "--spp", "3"});
}

TEST_F(Distributed, BidirectionalIsBitIdentical) {
    // bdpt splats its t = 1 strategies onto other tiles' pixels as well as writing its own.
    expect_identical(*this, dir.path(), "bdpt",
                     {Scenes + "render/cornell-box.xml", "-D", "res=40", "-D", "integrator=bdpt", "--spp", "2"});
}

TEST_F(Distributed, AovChannelsAreBitIdentical) {
    expect_identical(*this, dir.path(), "aov", {Scenes + "render/aov.xml", "-D", "res=40", "--spp", "2"});
}

TEST_F(Distributed, CropWindowIsBitIdentical) {
    expect_identical(*this, dir.path(), "crop",
                     {Scenes + "render/cornell-box.xml", "-D", "res=64", "--spp", "2", "--crop", "8,56,20,50"});
}

// More ranks than work units: a 24 x 24 film is one tile and one block of light paths, and 2 chains over 3 ranks
// leave rank 2 with nothing to do. Such a rank must still take part in every collective (a rank that skipped one
// would hang the run) and contribute nothing to the sums.
TEST_F(Distributed, RanksWithoutWorkUnitsTakePartAndAddNothing) {
    auto three_ranks = [&](const std::string& name, std::vector<std::string> args) {
        const fs::path one = dir.path() / (name + "_alone.exr"), np3 = dir.path() / (name + "_np3.exr");
        std::vector<std::string> a = args, b = args;
        a.insert(a.end(), {"-q", "-o", one.string()});
        b.insert(b.end(), {"-q", "-o", np3.string()});
        ProcessResult r = alone(a);
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        r = mpirun(3, b, 60);
        ASSERT_FALSE(r.timed_out) << describe(r);
        ASSERT_EQ(r.exit_code, 0) << describe(r);
        EXPECT_TRUE(has_light(one)) << name;
        EXPECT_TRUE(same_bits(one, np3)) << name;
    };
    three_ranks("path", {Scenes + "render/cornell-box.xml", "-D", "res=24", "--spp", "2"});
    three_ranks("ptracer",
                {Scenes + "render/cornell-box.xml", "-D", "res=24", "-D", "integrator=ptracer", "--spp", "2"});
    three_ranks("pssmlt", {Scenes + "render/mlt-study.xml", "-D", "variant=pssmlt-kelemen", "-D", "res=12", "-D",
                           "chains=2", "--spp", "2"});
}

// --- Metropolis: bootstrap blocks and chains are units; splats are fixed-point integer sums

TEST_F(Distributed, PssmltIsBitIdentical) {
    expect_identical(*this, dir.path(), "pssmlt",
                     {Scenes + "render/mlt-study.xml", "-D", "variant=pssmlt-kelemen", "-D", "res=24", "--spp", "4"});
}

TEST_F(Distributed, DrmltOrbitalIsBitIdentical) {
    // Also the stage channels (stages.R, stages.G): per-pixel acceptance counts summed over ranks.
    expect_identical(*this, dir.path(), "drmlt",
                     {Scenes + "render/mlt-study.xml", "-D", "variant=drmlt-orbital", "-D", "res=24", "--spp", "4"});
}

TEST_F(Distributed, DrmltGreenMiraOnBdptIsBitIdentical) {
    expect_identical(*this, dir.path(), "green",
                     {Scenes + "render/mlt-study.xml", "-D", "variant=drmlt-green", "-D", "technique=bdpt", "-D",
                      "max_depth=6", "-D", "res=20", "--spp", "3"});
}

TEST_F(Distributed, MultiplexedDrmltIsBitIdentical) {
    // Chains per path length, each with its own normalisation from the shared bootstrap.
    expect_identical(*this, dir.path(), "mmlt",
                     {Scenes + "render/mlt-study.xml", "-D", "variant=drmlt-orbital", "-D", "technique=mmlt", "-D",
                      "max_depth=5", "-D", "direct_samples=-1", "-D", "res=20", "--spp", "3"});
}

TEST_F(Distributed, ComparisonSeesADifferentSeed) {
    // The comparison can fail: the same render with another seed is not bit-identical.
    const fs::path a = dir.path() / "a.exr", b = dir.path() / "b.exr";
    ASSERT_EQ(
        alone({Scenes + "render/cornell-box.xml", "-D", "res=32", "--spp", "2", "-q", "-o", a.string()}).exit_code, 0);
    ASSERT_EQ(mpirun(2, {Scenes + "render/cornell-box.xml", "-D", "res=32", "--spp", "2", "--seed", "1", "-q", "-o",
                         b.string()})
                  .exit_code,
              0);
    EXPECT_FALSE(same_bits(a, b));
}

// --- behaving as one process

TEST_F(Distributed, OnlyRankZeroReportsAndWrites) {
    const fs::path out = dir.path() / "img.exr", stats = dir.path() / "stats.json";
    ProcessResult r = mpirun(2, {Scenes + "render/cornell-box.xml", "-D", "res=32", "--spp", "2", "-o", out.string(),
                                 "--stats", stats.string()});
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(count_lines(r.err, "Done: path"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "on 2 ranks x"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "wrote "), 2u) << r.err;
    // Statistics are the whole run's: 36 x 36 pixels (the film's 32 and the 2 beyond each edge that splatting
    // samples) x 2 spp camera samples, not one rank's share.
    const std::string json = read_file(stats);
    EXPECT_TRUE(std::regex_search(json, std::regex("\"render.camera_samples\": \\{\\s*\"unit\": \"samples\",\\s*"
                                                   "\"value\": 2592(\\.0)?\\s*\\}")))
        << json;
}

TEST_F(Distributed, TimeLimitStopsEveryRankTogether) {
    // A time limit with no sample count: rank 0's clock decides for everyone, so both ranks stop after the same
    // pass and the run ends (a rank left waiting in a collective would hang it).
    const fs::path out = dir.path() / "timed.exr";
    ProcessResult r = mpirun(2,
                             {Scenes + "render/mlt-study.xml", "-D", "res=24", "--time-limit", "1.5", "--write-partial",
                              "0.3", "-o", out.string()},
                             60);
    ASSERT_FALSE(r.timed_out) << describe(r);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_EQ(count_lines(r.err, "Done: drmlt"), 1u) << r.err;
    EXPECT_TRUE(has_light(out));
}

TEST_F(Distributed, InterruptedRunWritesOnePartialImage) {
    // Ctrl-C reaches mpirun, which passes SIGTERM to the ranks: they stop together, rank 0 writes the image so far.
    const fs::path out = dir.path() / "partial.exr";
    std::vector<std::string> a = {
        "-np", "2",      "--oversubscribe", "--quiet", KELVIN_CLI, Scenes + "render/cornell-box.xml",
        "-D",  "res=48", "--spp",           "1000000", "-o",       out.string()};
    Process p(Mpiexec, a, MpiEnv);
    ASSERT_TRUE(
        p.wait_until([&] { return p.stderr_so_far().find("spp") != std::string::npos; }, std::chrono::seconds(60)))
        << p.stderr_so_far();
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    p.signal(SIGINT);
    ProcessResult r = p.wait(std::chrono::seconds(60));
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_NE(r.exit_code, 0) << describe(r);  // mpirun's own status after Ctrl-C (the ranks exit 130)
    EXPECT_EQ(count_lines(r.err, "Interrupted: path"), 1u) << r.err;
    EXPECT_EQ(count_lines(r.err, "wrote "), 1u) << r.err;
    ASSERT_TRUE(fs::exists(out)) << r.err;
    EXPECT_TRUE(has_light(out));
}

TEST_F(Distributed, SignalToOneRankStopsAll) {
    // A signal that reaches one rank only (a batch system, a node's watchdog): the other rank learns it at the end
    // of the pass, and the run ends as interrupted with exit code 130.
    const fs::path out = dir.path() / "one.exr";
    std::vector<std::string> a = {
        "-np", "2",      "--oversubscribe", "--quiet", KELVIN_CLI, Scenes + "render/cornell-box.xml",
        "-D",  "res=48", "--spp",           "1000000", "-o",       out.string()};
    Process p(Mpiexec, a, MpiEnv);
    ASSERT_TRUE(
        p.wait_until([&] { return p.stderr_so_far().find("spp") != std::string::npos; }, std::chrono::seconds(60)));
    // The ranks are mpirun's children; signal the first of them.
    const ProcessResult ps = run_process("/usr/bin/pgrep", {"-P", std::to_string(p.pid())}, {});
    const std::vector<std::string> pids = lines_of(ps.out);
    ASSERT_FALSE(pids.empty()) << ps.out << ps.err;
    ::kill(std::stoi(pids.front()), SIGTERM);
    ProcessResult r = p.wait(std::chrono::seconds(60));
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, 130) << describe(r);
    EXPECT_EQ(count_lines(r.err, "Interrupted: path"), 1u) << r.err;
    EXPECT_TRUE(has_light(out));
}

TEST_F(Distributed, BadSceneIsOneErrorLineAndExitTwo) {
    const fs::path bad = dir.path() / "bad.xml";
    write_file(bad,
               "<scene version=\"3.0.0\">\n  <integrator type=\"path\"><integer name=\"max_depth\" value=\"x\"/>"
               "</integrator>\n</scene>\n");
    ProcessResult r = mpirun(2, {bad.string(), "-o", (dir.path() / "bad.exr").string()}, 60);
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, 2) << describe(r);
    ASSERT_EQ(r.err_lines().size(), 1u) << r.err;
    EXPECT_TRUE(std::regex_search(r.err, std::regex("^kelvin: error: .*bad\\.xml:2:"))) << r.err;
    EXPECT_FALSE(fs::exists(dir.path() / "bad.exr"));
}

TEST_F(Distributed, AFileOnlyOneRankCannotReadIsOneErrorNoHang) {
    // The scene exists for rank 0 only (the file name differs per rank through OpenMPI's per-rank environment,
    // OMPI_COMM_WORLD_RANK): rank 1 fails to load, rank 0 must not wait for it in a collective, and the one error
    // line names the rank.
    fs::create_symlink(Scenes + "render/cornell-box.xml", dir.path() / "scene_0.xml");
    // Rank r loads scene_$OMPI_COMM_WORLD_RANK.xml through a tiny shell wrapper.
    const fs::path wrapper = dir.path() / "per_rank.sh";
    write_file(wrapper,
               "#!/bin/sh\nexec \"$@\" \"" + (dir.path() / "scene_").string() + "$OMPI_COMM_WORLD_RANK.xml\"\n");
    fs::permissions(wrapper, fs::perms::owner_all);
    ProcessResult r = run_process(Mpiexec,
                                  {"-np", "2", "--oversubscribe", "--quiet", wrapper.string(), KELVIN_CLI, "-D",
                                   "res=16", "--spp", "1", "-o", (dir.path() / "x.exr").string()},
                                  MpiEnv, std::chrono::seconds(60));
    ASSERT_FALSE(r.timed_out) << describe(r);
    EXPECT_EQ(r.exit_code, 2) << describe(r);
    ASSERT_EQ(r.err_lines().size(), 1u) << r.err;
    EXPECT_TRUE(std::regex_search(r.err, std::regex("^kelvin: error: rank 1: .*scene_1\\.xml"))) << r.err;
}

}  // namespace
}  // namespace kelvin::test

// --- kelvin converge: the runs of a study are the units

namespace kelvin::test {
namespace {

// convergence.csv without its timing column (seconds): what a study computes, which must not depend on the ranks.
std::string csv_without_seconds(const fs::path& p) {
    std::string out;
    for (const auto& line : lines_of(read_file(p))) {
        std::vector<std::string> f;
        std::size_t at = 0;
        for (std::size_t c; (c = line.find(',', at)) != std::string::npos; at = c + 1)
            f.push_back(line.substr(at, c - at));
        f.push_back(line.substr(at));
        if (f.size() > 5) f.erase(f.begin() + 5);
        for (const auto& x : f) out += x + ",";
        out += "\n";
    }
    return out;
}

class DistributedConverge : public Distributed {
public:
    std::vector<std::string> study(const fs::path& ref, const fs::path& out, int runs) {
        return {"converge",
                Scenes + "tests/converge.xml",
                "-q",
                "--reference",
                ref.string(),
                "--config",
                "path:integrator=path",
                "--config",
                "pt:integrator=ptracer",
                "--runs",
                std::to_string(runs),
                "--spp",
                "1,4,16",
                "-o",
                out.string()};
    }
    fs::path reference() {
        const fs::path ref = dir.path() / "ref.exr";
        const ProcessResult r =
            alone({Scenes + "tests/converge.xml", "-q", "--spp", "64", "--seed", "1000", "-o", ref.string()});
        EXPECT_EQ(r.exit_code, 0) << describe(r);
        return ref;
    }
};

TEST_F(DistributedConverge, StudyOverRanksWritesTheSingleProcessCsv) {
    const fs::path ref = reference(), one = dir.path() / "one", two = dir.path() / "two";
    ProcessResult r = alone(study(ref, one, 3));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    r = mpirun(2, study(ref, two, 3));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    const std::string a = csv_without_seconds(one / "convergence.csv"),
                      b = csv_without_seconds(two / "convergence.csv");
    EXPECT_EQ(lines_of(a).size(), 1u + 2 * 3 * 3);  // header, 2 configurations x 3 runs x 3 checkpoints
    EXPECT_EQ(a, b);
    // Each rank wrote the checkpoint images of the runs it ran (run 0 of path on rank 0, of pt on rank 1).
    EXPECT_TRUE(fs::exists(two / "images" / "path" / "run0_spp16.exr"));
    EXPECT_TRUE(fs::exists(two / "images" / "pt" / "run0_spp16.exr"));
    EXPECT_TRUE(same_bits(one / "images" / "pt" / "run0_spp16.exr", two / "images" / "pt" / "run0_spp16.exr"));
}

TEST_F(DistributedConverge, ResumesAStudyStartedByOneProcess) {
    const fs::path ref = reference(), one = dir.path() / "one", two = dir.path() / "two";
    ProcessResult r = alone(study(ref, one, 3));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    // One run per configuration alone, then the rest over two ranks, then nothing left to do.
    r = alone(study(ref, two, 1));
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    std::vector<std::string> a = study(ref, two, 3);
    a.erase(std::find(a.begin(), a.end(), "-q"));
    r = mpirun(2, a);
    ASSERT_EQ(r.exit_code, 0) << describe(r);
    EXPECT_NE(r.err.find("Done: 4 run(s)"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("(2 already done)"), std::string::npos) << r.err;
    EXPECT_EQ(csv_without_seconds(one / "convergence.csv"), csv_without_seconds(two / "convergence.csv"));
}

TEST_F(DistributedConverge, BadStudyIsOneErrorLine) {
    const fs::path ref = reference();
    ProcessResult r = mpirun(2, {"converge", Scenes + "tests/converge.xml", "--reference", ref.string(), "--config",
                                 "x:nonexistent_parameter=1", "--spp", "1", "-o", (dir.path() / "bad").string()});
    ASSERT_FALSE(r.timed_out);
    EXPECT_EQ(r.exit_code, 2) << describe(r);
    ASSERT_EQ(r.err_lines().size(), 1u) << r.err;
    EXPECT_NE(r.err.find("nonexistent_parameter"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace kelvin::test
