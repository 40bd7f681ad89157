#pragma once
// What the distributed-run tests share (issue 21): the real `kelvin` under the real MPI launcher on localhost,
// `kelvin` alone, and bit-for-bit comparisons of the images they write.
#include "cli/subprocess.h"

#include <kelvin/core/image.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <string>
#include <vector>

namespace kelvin::test {

#ifdef KELVIN_MPIEXEC
inline const std::string Mpiexec = KELVIN_MPIEXEC;
#else
inline const std::string Mpiexec;
#endif
inline const std::string Scenes = std::string(KELVIN_SOURCE_DIR) + "/scenes/";

// OpenMPI refuses root without these (CI runs as root); never more ranks than asked.
inline const std::map<std::string, std::string> MpiEnv = {{"OMPI_ALLOW_RUN_AS_ROOT", "1"},
                                                          {"OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1"}};

/// A test that runs `kelvin` under mpirun; skipped when this build has no MPI module.
class MpiTest : public ::testing::Test {
public:
    void SetUp() override {
        if (Mpiexec.empty() ||
            !fs::exists(fs::path(KELVIN_CLI).parent_path().parent_path() / "lib" / "libkelvin_mpi.so"))
            GTEST_SKIP() << "this build has no MPI module (install libopenmpi-dev and reconfigure)";
    }
    // `kelvin args...` under mpirun with `np` ranks; --quiet keeps mpirun's own banners out of stderr.
    ProcessResult mpirun(int np, std::vector<std::string> args, double timeout = 120) {
        std::vector<std::string> a = {"-np", std::to_string(np), "--oversubscribe", "--quiet", KELVIN_CLI};
        a.insert(a.end(), args.begin(), args.end());
        return run_process(Mpiexec, a, MpiEnv, std::chrono::duration<double>(timeout));
    }
    ProcessResult alone(std::vector<std::string> args) {
        return run_process(KELVIN_CLI, args, {}, std::chrono::seconds(120));
    }
    TempDir dir;
};

/// Same size, channels and bits; on failure, how many values differ and the largest difference.
inline ::testing::AssertionResult same_bits(const fs::path& a, const fs::path& b) {
    const Bitmap x = read_image(a), y = read_image(b);
    if (x.width() != y.width() || x.height() != y.height() || x.channels() != y.channels())
        return ::testing::AssertionFailure() << a << " and " << b << " differ in size or channels";
    const std::size_t n = x.size();
    if (n == 0) return ::testing::AssertionFailure() << a << " is empty";
    if (std::memcmp(x.data(), y.data(), n * sizeof(float)) == 0) return ::testing::AssertionSuccess();
    std::size_t differ = 0;
    double worst = 0;
    for (std::size_t i = 0; i < n; ++i)
        if (std::memcmp(&x.data()[i], &y.data()[i], sizeof(float)) != 0) {
            ++differ;
            worst = std::max(worst, double(std::abs(x.data()[i] - y.data()[i])));
        }
    return ::testing::AssertionFailure() << a << " and " << b << ": " << differ << " of " << n
                                         << " values differ, largest difference " << worst;
}

/// Lines of `text` that contain `needle`.
inline std::size_t count_lines(const std::string& text, const std::string& needle) {
    std::size_t n = 0;
    for (const auto& l : lines_of(text))
        if (l.find(needle) != std::string::npos) ++n;
    return n;
}

}  // namespace kelvin::test
