// Input checks, output probes and atomic writes (include/kelvin/core/files.h).
#include <kelvin/core/files.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cstring>

namespace kelvin {

namespace fs = std::filesystem;

namespace {

std::atomic<unsigned long long> g_counter{0};

// Temporary files in flight, for remove_temporary_files() in a signal handler: fixed storage, lock-free
// state (0 free, 1 being filled, 2 live). A path that does not fit, or a full table, is simply not registered.
constexpr int TempSlots = 64;
constexpr std::size_t TempPathMax = 4096;
struct TempSlot {
    std::atomic<int> state{0};
    char path[TempPathMax];
};
std::array<TempSlot, TempSlots> g_temps;

int register_temp(const fs::path& p) {
    std::error_code ec;
    fs::path abs = fs::absolute(p, ec);
    const std::string s = (ec ? p : abs).string();
    if (s.size() + 1 > TempPathMax) return -1;
    for (int i = 0; i < TempSlots; ++i) {
        int expected = 0;
        if (g_temps[std::size_t(i)].state.compare_exchange_strong(expected, 1)) {
            std::memcpy(g_temps[std::size_t(i)].path, s.c_str(), s.size() + 1);
            g_temps[std::size_t(i)].state.store(2, std::memory_order_release);
            return i;
        }
    }
    return -1;
}

void unregister_temp(int slot) {
    if (slot >= 0) g_temps[std::size_t(slot)].state.store(0, std::memory_order_release);
}

// The longest file name `dir` takes (NAME_MAX: 255 bytes on ext4, xfs, btrfs, tmpfs).
std::size_t name_max(const fs::path& dir) {
    errno = 0;
    const long n = ::pathconf(dir.empty() ? "." : dir.c_str(), _PC_NAME_MAX);
    return n > 0 ? std::size_t(n) : 255;
}

std::string probe_dir(const fs::path& dir) {
    const fs::path probe = dir / fmt::format(".kelvin-probe-{}-{}", long(::getpid()), g_counter.fetch_add(1));
    const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (fd < 0) return fmt::format("cannot create a file in '{}': {}", dir.string(), std::strerror(errno));
    ::close(fd);
    ::unlink(probe.c_str());
    return {};
}

}  // namespace

std::string input_file_problem(const fs::path& path, std::string_view what) {
    if (path.empty()) return fmt::format("no {} given (empty file name)", what);
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (ec && ec != std::errc::no_such_file_or_directory && ec != std::errc::not_a_directory)
        return fmt::format("cannot access {} '{}': {}", what, path.string(), ec.message());
    if (!fs::exists(st)) return fmt::format("{} '{}' does not exist", what, path.string());
    if (fs::is_directory(st)) return fmt::format("{} '{}' is a directory", what, path.string());
    if (!fs::is_regular_file(st))
        return fmt::format("{} '{}' is not a regular file (a device, pipe or socket would never be read to the end)",
                           what, path.string());
    return {};
}

void check_input_file(const fs::path& path, std::string_view what, const SourceLoc& loc) {
    if (std::string why = input_file_problem(path, what); !why.empty()) throw InputError(loc, why);
}

fs::path resolve_file(const fs::path& name, const fs::path& near, const std::vector<fs::path>& search_path,
                      bool directory) {
    if (name.empty() || name.is_absolute()) return name;
    std::error_code ec;
    auto found = [&](const fs::path& p) { return directory ? fs::is_directory(p, ec) : fs::exists(p, ec); };
    const fs::path first = (near / name).lexically_normal();
    if (found(first)) return first;
    for (const auto& dir : search_path) {
        if (dir.empty()) continue;
        const fs::path candidate = (dir / name).lexically_normal();
        if (found(candidate)) return candidate;
    }
    return first;
}

std::string searched_folders(const fs::path& near, const std::vector<fs::path>& search_path) {
    std::vector<std::string> seen;
    auto add = [&](const fs::path& d) {
        std::string s = d.empty() ? std::string(".") : d.lexically_normal().string();
        if (std::find(seen.begin(), seen.end(), s) == seen.end()) seen.push_back(std::move(s));
    };
    add(near);
    for (const auto& d : search_path)
        if (!d.empty()) add(d);
    std::string out;
    if (seen.size() < 2) return out;  // only `near`: the candidate's own path says it all
    for (const auto& s : seen) out += (out.empty() ? "'" : ", '") + s + "'";
    return out;
}

std::string output_file_problem(const fs::path& path) {
    if (path.empty()) return "empty output path";
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);
    if (fs::is_directory(st)) return "is a directory";
    if (fs::exists(st) && !fs::is_regular_file(st)) return "exists and is not a regular file";
    fs::path dir = path.parent_path();
    if (dir.empty()) dir = ".";
    const fs::file_status ds = fs::status(dir, ec);
    if (!fs::exists(ds)) return fmt::format("directory '{}' does not exist", dir.string());
    if (!fs::is_directory(ds)) return fmt::format("'{}' is not a directory", dir.string());
    if (const std::size_t n = path.filename().string().size(), limit = name_max(dir); n > limit)
        return fmt::format("the file name is {} bytes long, more than the {} its directory takes", n, limit);
    return probe_dir(dir);
}

bool same_file(const fs::path& a, const fs::path& b) {
    std::error_code ec;
    if (fs::exists(a, ec) && fs::exists(b, ec)) return fs::equivalent(a, b, ec) && !ec;
    const fs::path ca = fs::weakly_canonical(fs::absolute(a, ec), ec);
    const fs::path cb = fs::weakly_canonical(fs::absolute(b, ec), ec);
    return ca.lexically_normal() == cb.lexically_normal();
}

std::string output_dir_problem(const fs::path& dir) {
    if (dir.empty()) return "empty output directory";
    std::error_code ec;
    fs::path d = dir;
    for (;;) {
        const fs::file_status st = fs::status(d, ec);
        if (fs::exists(st)) {
            if (!fs::is_directory(st)) return fmt::format("'{}' exists and is not a directory", d.string());
            return probe_dir(d);
        }
        fs::path parent = d.parent_path();
        if (parent.empty()) parent = ".";
        if (parent == d) return fmt::format("'{}' does not exist", d.string());
        d = parent;
    }
}

AtomicFile::AtomicFile(fs::path target) : m_target(std::move(target)) {
    // NAME.partial-PID-N.EXT, with NAME shortened when the whole would not fit the directory's name limit (a
    // target name that itself fits must never fail at the end of a run for its temporary name). The extension
    // stays: writers pick the format by it.
    const std::string suffix = fmt::format(".partial-{}-{}", long(::getpid()), g_counter.fetch_add(1));
    const std::string ext = m_target.extension().string();
    std::string stem = m_target.stem().string();
    const std::size_t limit = name_max(m_target.parent_path());
    if (stem.size() + suffix.size() + ext.size() > limit) {
        stem.resize(limit > suffix.size() + ext.size() ? limit - suffix.size() - ext.size() : 0);
        while (!stem.empty() && (static_cast<unsigned char>(stem.back()) & 0xC0) == 0x80) stem.pop_back();
        if (!stem.empty() && static_cast<unsigned char>(stem.back()) >= 0xC0) stem.pop_back();
    }
    m_temp = m_target.parent_path() / (stem + suffix + ext);
    m_slot = register_temp(m_temp);  // before the file exists: a signal at any moment finds it
}

AtomicFile::~AtomicFile() {
    if (!m_done) discard();
}

void AtomicFile::discard() noexcept {
    if (m_done) return;
    ::unlink(m_temp.c_str());
    unregister_temp(m_slot);
    m_done = true;
}

void AtomicFile::commit() {
    if (m_done) throw RuntimeError(fmt::format("cannot write '{}': the temporary file is gone", m_target.string()));
    auto fail = [&](const char* step, int err) {
        discard();
        throw RuntimeError(fmt::format("cannot write '{}': {}: {}", m_target.string(), step, std::strerror(err)));
    };
    // Flush to the disk before the rename, so that the new name never points at data still in flight.
    const int fd = ::open(m_temp.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) fail("cannot reopen the temporary file", errno);
    if (::fsync(fd) != 0 && errno != EINVAL && errno != EROFS) {
        const int err = errno;
        ::close(fd);
        fail("cannot flush the temporary file", err);
    }
    ::close(fd);
    if (std::rename(m_temp.c_str(), m_target.c_str()) != 0) fail("cannot rename the temporary file", errno);
    unregister_temp(m_slot);
    m_done = true;
}

void write_atomically(const fs::path& path, const std::function<void(const fs::path&)>& write) {
    AtomicFile file(path);
    try {
        write(file.temp_path());
    } catch (const InputError&) {
        throw;
    } catch (const std::exception& e) {
        file.discard();
        throw RuntimeError(fmt::format("cannot write '{}': {}", path.string(), e.what()));
    }
    file.commit();
}

void write_text_atomically(const fs::path& path, std::string_view text) {
    write_atomically(path, [&](const fs::path& tmp) {
        const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        if (fd < 0) throw RuntimeError(std::strerror(errno));
        std::size_t done = 0;
        while (done < text.size()) {
            const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
            if (n < 0) {
                if (errno == EINTR) continue;
                const int err = errno;
                ::close(fd);
                throw RuntimeError(std::strerror(err));
            }
            done += std::size_t(n);
        }
        if (::close(fd) != 0) throw RuntimeError(std::strerror(errno));
    });
}

void remove_temporary_files() noexcept {
    for (auto& slot : g_temps)
        if (slot.state.load(std::memory_order_acquire) == 2) ::unlink(slot.path);
}

}  // namespace kelvin
