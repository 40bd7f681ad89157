#pragma once
// Files in and out, checked the same way everywhere.
//
// Inputs: every file a scene names (scene includes, images, meshes, polylines, volumes) is checked to be a
// regular file before any reader opens it: a device (/dev/zero), a pipe or a directory would make a reader
// hang or fail with a misleading message.
//
// Outputs: checked before any work starts (the directory exists and takes a probe file, the path is not a
// directory), and written atomically: a temporary file in the same directory, flushed to disk, renamed over
// the target. A failed write leaves the previous file as it was. The temporary files in flight are
// registered, so that a second Ctrl-C, which exits at once, removes them (remove_temporary_files).
#include <kelvin/core/error.h>

#include <filesystem>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

namespace kelvin {

/// Why `path` cannot be read as a `what` (e.g. "image file"): it does not exist, is a directory, or is not a
/// regular file (a device, pipe or socket). Empty when it is a regular file (symbolic links are followed).
std::string input_file_problem(const std::filesystem::path& path, std::string_view what);
/// Throws InputError(loc, input_file_problem(...)) when there is a problem.
void check_input_file(const std::filesystem::path& path, std::string_view what, const SourceLoc& loc = {});

/// The file resolver (Mitsuba's FileResolver, one mechanism for every file a scene names: meshes, images,
/// included scene files, volume grids, boundary files, <path> folders). A relative `name` is looked for first in
/// `near` (the folder of the scene file that names it; empty: the working directory), then in each folder of
/// `search_path` in order (the scene's <path> folders, the most recently declared first, then the folder of the
/// root scene file). Returns the first candidate that exists (with `directory`, the first that is a folder);
/// when none does, `near / name`, so that the error names it. An absolute `name` is returned unchanged.
std::filesystem::path resolve_file(const std::filesystem::path& name, const std::filesystem::path& near,
                                   const std::vector<std::filesystem::path>& search_path, bool directory = false);
/// The folders resolve_file looked in, for an error message: "'near', 'a', 'b'" (each once, in order); empty
/// when it looked in `near` only.
std::string searched_folders(const std::filesystem::path& near, const std::vector<std::filesystem::path>& search_path);

/// Why a file cannot be created (or replaced) at `path`: it is a directory, its directory does not exist or
/// does not take a new file (a probe file is created and removed; the message has the system error). Empty
/// when it can.
std::string output_file_problem(const std::filesystem::path& path);
/// The same for a directory that will hold outputs: an existing one must take a probe file; a missing one
/// (created later) needs its nearest existing ancestor to be a directory that takes one.
std::string output_dir_problem(const std::filesystem::path& dir);
/// True when `a` and `b` name one file: the same inode when both exist (hard and symbolic links too), else the
/// same absolute path once "." and ".." and symbolic links of the existing part are resolved.
bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

/// A temporary file beside `target` (same directory, same extension: writers that pick the format by
/// extension see the right one) that replaces `target` on commit(). Destroyed uncommitted, it is removed.
/// Registered while it exists, so that remove_temporary_files() can delete it from a signal handler.
class AtomicFile {
public:
    explicit AtomicFile(std::filesystem::path target);
    ~AtomicFile();
    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;

    const std::filesystem::path& target() const { return m_target; }
    const std::filesystem::path& temp_path() const { return m_temp; }
    /// Flush the temporary file to disk and rename it over the target. RuntimeError naming the target and
    /// the system error on failure (the temporary file is then removed, the target untouched).
    void commit();
    /// Remove the temporary file now (idempotent).
    void discard() noexcept;

private:
    std::filesystem::path m_target, m_temp;
    int m_slot = -1;
    bool m_done = false;
};

/// Write `path` atomically: `write` writes the temporary file it is given, then it is flushed and renamed.
/// Any exception from `write` (or the rename) removes the temporary file, leaves `path` as it was and becomes
/// a RuntimeError "cannot write 'path': reason" (InputErrors pass through unchanged).
void write_atomically(const std::filesystem::path& path,
                      const std::function<void(const std::filesystem::path&)>& write);
/// write_atomically for a text (CSV, settings).
void write_text_atomically(const std::filesystem::path& path, std::string_view text);

/// Delete every temporary file of an AtomicFile alive now. Async-signal-safe (unlink only): the second-signal
/// handler calls it before _Exit.
void remove_temporary_files() noexcept;

}  // namespace kelvin
