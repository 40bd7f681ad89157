#pragma once
// Reading input files with a stop check and a memory estimate.
//
// Loaders (meshes, scene files) read their whole file before parsing it. They read it in chunks, polling
// interrupt_requested() between chunks (a few milliseconds of work each), and throw Interrupted when a stop was
// requested; the parser's instantiate() and parse_scene_file() turn that into an empty result, which the CLI reports
// as "interrupted while loading" (exit 130). Before reading, the memory the parsed data will need is estimated from
// the file's size (a per-format ratio, measured) and checked with check_memory (core/memory.h), so that a file too
// large for the machine (or a sparse 50 GB file) is refused at once instead of read for minutes.
#include <kelvin/core/error.h>

#include <cstdint>
#include <filesystem>
#include <streambuf>
#include <string>
#include <string_view>

namespace kelvin {

/// A stop was requested (interrupt_requested()) while loading input. Not an InputError: the input may be fine.
class Interrupted : public Error {
public:
    Interrupted() : Error("interrupted while loading") {}
};

/// Throws Interrupted if a stop was requested.
void throw_if_interrupted();

/// The size of a regular file in bytes (0 when it cannot be read: the reader reports that).
uint64_t file_size_or_zero(const std::filesystem::path& path);

/// Read the whole file in chunks, polling for a stop between them (throws Interrupted). First checks the memory
/// the load will need, `bytes_per_file_byte` times the file size (check_memory: "<what> '<file>'" at `loc`).
/// Throws InputError(loc) when the file cannot be read.
std::string read_file_polling(const std::filesystem::path& path, std::string_view what, const SourceLoc& loc,
                              double bytes_per_file_byte);

/// A read-only stream buffer over text that polls for a stop every chunk it hands out: a reader that parses from a
/// std::istream (tinyobjloader) sees the end of the stream when a stop is requested; stopped() then tells.
class PollingStringBuf : public std::streambuf {
public:
    explicit PollingStringBuf(std::string_view text, std::size_t chunk = std::size_t(1) << 18);
    bool stopped() const { return m_stopped; }

protected:
    int_type underflow() override;

private:
    std::string_view m_text;
    std::size_t m_pos = 0, m_chunk;
    bool m_stopped = false;
};

}  // namespace kelvin
