#pragma once
// Videos from image frames with Debian's ffmpeg (a program on PATH, not a library: nothing is linked). Used by the
// fluid runs' `write_video` and by `kelvin --frames ... --video`.
#include <filesystem>
#include <string>
#include <vector>

namespace kelvin {

/// The first executable `name` on PATH (empty when there is none).
std::filesystem::path find_on_path(const std::string& name);

/// Encode `frames` (image files, in order, each shown 1 / fps seconds) into an H.264 MP4 at `out` (written
/// atomically; odd sizes padded to even). Returns an empty string on success, else why not, in one line (ffmpeg not
/// found, or its exit status and first error line).
std::string encode_video(const std::vector<std::filesystem::path>& frames, double fps,
                         const std::filesystem::path& out);

}  // namespace kelvin
