#include <kelvin/core/error.h>
#include <kelvin/core/files.h>
#include <kelvin/core/video.h>

#include <fcntl.h>
#include <fmt/format.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <sstream>

extern char** environ;

namespace kelvin {

namespace fs = std::filesystem;

fs::path find_on_path(const std::string& name) {
    const char* path = std::getenv("PATH");
    std::stringstream dirs(path ? path : "/usr/bin:/bin");
    std::string d;
    while (std::getline(dirs, d, ':')) {
        const fs::path p = fs::path(d.empty() ? "." : d) / name;
        if (::access(p.c_str(), X_OK) == 0) return p;
    }
    return {};
}

namespace {

// Runs `args` (args[0] found on PATH) with stdout discarded and stderr into `log`; the exit status (-1: not run).
int run_program(const std::vector<std::string>& args, const fs::path& log) {
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_addopen(&fa, 2, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    pid_t pid = 0;
    const int rc = posix_spawnp(&pid, args[0].c_str(), &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) return -1;
    int status = 0;
    while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

std::string encode_video(const std::vector<fs::path>& frames, double fps, const fs::path& out) {
    if (frames.empty()) return "no frames";
    if (find_on_path("ffmpeg").empty()) return "ffmpeg is not on PATH (Debian: apt-get install ffmpeg)";
    const std::string ext = frames.front().extension().string();
    for (const auto& f : frames)
        if (f.extension() != ext) return fmt::format("the frames mix {} and {} files", ext, f.extension().string());
    // The frames as a numbered sequence (links in a temporary folder), read at `fps`: exactly one video frame per
    // image, whatever the names (ffmpeg's concat list with durations can drop the last frame to rounding).
    const fs::path dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
    const fs::path seq = dir / fmt::format(".{}_frames", out.filename().string()), log = seq / "ffmpeg.log";
    std::error_code ec;
    fs::remove_all(seq, ec);
    fs::create_directories(seq, ec);
    if (ec) return fmt::format("cannot create {}: {}", seq.string(), ec.message());
    for (std::size_t i = 0; i < frames.size(); ++i) {
        const fs::path link = seq / fmt::format("{:06d}{}", i, ext);
        fs::create_symlink(fs::absolute(frames[i]), link, ec);
        if (ec) fs::copy_file(frames[i], link, ec);
        if (ec) {
            fs::remove_all(seq, ec);
            return fmt::format("cannot link {}", frames[i].string());
        }
    }
    int status = -1;
    try {
        write_atomically(out, [&](const fs::path& tmp) {
            status = run_program(
                {"ffmpeg", "-nostdin", "-y", "-loglevel", "error", "-framerate", fmt::format("{:g}", fps), "-i",
                 (seq / ("%06d" + ext)).string(), "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2,format=yuv420p", "-c:v",
                 "libx264", "-r", fmt::format("{:g}", fps), "-f", "mp4", tmp.string()},
                log);
            if (status != 0) throw RuntimeError("ffmpeg failed");
        });
    } catch (const std::exception&) {
    }
    std::string why;
    if (status != 0) {
        std::ifstream in(log);
        std::string first;
        std::getline(in, first);
        why = fmt::format("ffmpeg {} ({})",
                          status < 0 ? std::string("could not run") : fmt::format("exited with {}", status),
                          first.empty() ? std::string("no message") : first);
    }
    fs::remove_all(seq, ec);
    return why;
}

}  // namespace kelvin
