// Files in and out (core/files.h): inputs must be regular files, outputs are probed before work and written
// atomically, so that a failed write (a full disk, a file size limit) keeps the previous file intact.
#include "test_support.h"

#include <kelvin/core/files.h>
#include <kelvin/core/image.h>

#include <algorithm>
#include <fstream>
#include <sstream>

using namespace kelvin;
namespace fs = std::filesystem;

namespace {

std::string slurp(const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream s;
    s << in.rdbuf();
    return s.str();
}

/// Names of the files in `dir`.
std::vector<std::string> listing(const fs::path& dir) {
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
}

}  // namespace

TEST(Files, InputFileMustBeARegularFile) {
    ktest::TempDir dir;
    const fs::path ok = dir.write("a.txt", "x");
    EXPECT_EQ(input_file_problem(ok, "text file"), "");
    EXPECT_CONTAINS(input_file_problem(dir / "missing.png", "image file"), "does not exist");
    EXPECT_CONTAINS(input_file_problem(dir.path(), "image file"), "is a directory");
    const std::string dev = input_file_problem("/dev/zero", "image file");
    EXPECT_CONTAINS(dev, "'/dev/zero'");
    EXPECT_CONTAINS(dev, "not a regular file");
    SourceLoc at{"scene.xml", 3, 5};
    try {
        check_input_file("/dev/urandom", "OBJ file", at);
        ADD_FAILURE() << "no error for a device";
    } catch (const InputError& e) {
        EXPECT_EQ(std::string(e.what()).rfind("scene.xml:3:5: OBJ file '/dev/urandom'", 0), 0u) << e.what();
    }
}

TEST(Files, OutputPathIsProbedBeforeWork) {
    ktest::TempDir dir;
    EXPECT_EQ(output_file_problem(dir / "out.exr"), "");
    EXPECT_TRUE(listing(dir.path()).empty()) << "the probe file must be removed";
    EXPECT_CONTAINS(output_file_problem(dir.path()), "is a directory");
    EXPECT_CONTAINS(output_file_problem(dir / "no" / "out.exr"), "does not exist");
    // A directory that takes no new file, even for root: the message has the system error.
    const std::string proc = output_file_problem("/proc/kelvin-test-output.exr");
    EXPECT_CONTAINS(proc, "cannot create a file in '/proc'");
    EXPECT_GT(proc.size(), std::string("cannot create a file in '/proc': ").size()) << proc;
    // Output directories (converge): existing, to be created, or under something that is not a directory.
    EXPECT_EQ(output_dir_problem(dir.path()), "");
    EXPECT_EQ(output_dir_problem(dir / "new" / "deeper"), "");
    const fs::path file = dir.write("file", "x");
    EXPECT_CONTAINS(output_dir_problem(file), "not a directory");
    EXPECT_CONTAINS(output_dir_problem(file / "sub"), "not a directory");
    EXPECT_CONTAINS(output_dir_problem("/proc/kelvin-test-study"), "cannot create a file in '/proc'");
    EXPECT_EQ(listing(dir.path()), std::vector<std::string>{"file"});
}

TEST(Files, FailedAtomicWriteKeepsThePreviousFile) {
    ktest::TempDir dir;
    const fs::path p = dir / "table.csv";
    write_text_atomically(p, "old\n");
    EXPECT_EQ(slurp(p), "old\n");
    try {
        write_atomically(p, [](const fs::path& tmp) {
            std::ofstream(tmp) << "half of the new";
            throw std::runtime_error("No space left on device");
        });
        ADD_FAILURE() << "no error";
    } catch (const RuntimeError& e) {
        EXPECT_CONTAINS(std::string(e.what()), "cannot write '" + p.string() + "': No space left on device");
    }
    EXPECT_EQ(slurp(p), "old\n");
    EXPECT_EQ(listing(dir.path()), std::vector<std::string>{"table.csv"}) << "temporary file left behind";
    write_text_atomically(p, "new\n");
    EXPECT_EQ(slurp(p), "new\n");
    EXPECT_EQ(listing(dir.path()), std::vector<std::string>{"table.csv"});
}

TEST(Files, TemporaryFilesAreRemovedBySecondSignalCleanup) {
    // What the second Ctrl-C does before _Exit: every temporary file of a write in flight disappears.
    ktest::TempDir dir;
    AtomicFile a(dir / "a.exr"), b(dir / "b.csv");
    std::ofstream(a.temp_path()) << "partial";
    std::ofstream(b.temp_path()) << "partial";
    EXPECT_EQ(a.temp_path().parent_path(), dir.path());
    EXPECT_EQ(a.temp_path().extension(), ".exr");  // writers pick the format by extension
    EXPECT_EQ(listing(dir.path()).size(), 2u);
    remove_temporary_files();
    EXPECT_TRUE(listing(dir.path()).empty());
}
