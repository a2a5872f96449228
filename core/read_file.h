// Reading a whole file into memory: configs, summaries, caches, logs, camera models. The
// counterpart of core/atomic_file.h, whose writers these files come from.
//
// Errors: IoError (core/error.h) naming the path and what the system said, for a file that cannot
// be opened, a folder, or a read that fails part way.
#ifndef FLAMERIG_CORE_READ_FILE_H_
#define FLAMERIG_CORE_READ_FILE_H_

#include <optional>
#include <string>

namespace flamerig {

// The file's bytes. Throws IoError when it cannot be read whole.
std::string ReadFile(const std::string& path);

// The same, or nullopt when there is no such file (an absent cache, a log a child never wrote);
// a file that exists but cannot be read is still an IoError.
std::optional<std::string> ReadFileIfPresent(const std::string& path);

}  // namespace flamerig

#endif  // FLAMERIG_CORE_READ_FILE_H_
