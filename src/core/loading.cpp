// Reading input files with a stop check and a memory estimate (include/kelvin/core/loading.h).
#include <kelvin/core/interrupt.h>
#include <kelvin/core/loading.h>
#include <kelvin/core/memory.h>

#include <algorithm>
#include <fstream>
#include <system_error>

namespace kelvin {

void throw_if_interrupted() {
    if (interrupt_requested()) throw Interrupted();
}

uint64_t file_size_or_zero(const std::filesystem::path& path) {
    std::error_code ec;
    const auto n = std::filesystem::file_size(path, ec);
    return ec ? 0 : uint64_t(n);
}

std::string read_file_polling(const std::filesystem::path& path, std::string_view what, const SourceLoc& loc,
                              double bytes_per_file_byte) {
    const uint64_t size = file_size_or_zero(path);
    // The text itself is held too while it is parsed: at least one byte per byte.
    check_memory(double(size) * std::max(1.0, bytes_per_file_byte),
                 fmt::format("{} '{}' ({} on disk)", what, path.string(), format_bytes(double(size))), loc);
    std::ifstream in(path, std::ios::binary);
    if (!in) throw InputError(loc, fmt::format("cannot open {} '{}'", what, path.string()));
    std::string text;
    text.reserve(std::size_t(size));
    // 4 MiB per read: a few milliseconds from the page cache, so a stop is seen well within 0.1 s.
    constexpr std::size_t Chunk = std::size_t(4) << 20;
    std::string buffer(Chunk, '\0');
    for (;;) {
        throw_if_interrupted();
        in.read(buffer.data(), std::streamsize(Chunk));
        const std::streamsize got = in.gcount();
        if (got > 0) text.append(buffer.data(), std::size_t(got));
        if (!in) break;
    }
    if (in.bad()) throw InputError(loc, fmt::format("cannot read {} '{}'", what, path.string()));
    throw_if_interrupted();
    return text;
}

PollingStringBuf::PollingStringBuf(std::string_view text, std::size_t chunk) : m_text(text), m_chunk(chunk) {}

PollingStringBuf::int_type PollingStringBuf::underflow() {
    if (gptr() < egptr()) return traits_type::to_int_type(*gptr());
    if (m_pos >= m_text.size()) return traits_type::eof();
    if (interrupt_requested()) {  // the reader sees the end of its input; the caller checks stopped()
        m_stopped = true;
        return traits_type::eof();
    }
    const std::size_t n = std::min(m_chunk, m_text.size() - m_pos);
    char* b = const_cast<char*>(m_text.data() + m_pos);
    setg(b, b, b + n);
    m_pos += n;
    return traits_type::to_int_type(*gptr());
}

}  // namespace kelvin
