// The one exception hierarchy of flamerig (DESIGN section 2, README "Conventions").
//
// Every error that flamerig throws on purpose is a flamerig::Error, of one of three kinds, so that
// a caller can decide what to do by what happened rather than by which file threw it:
//
//   InputError  the user's input is wrong: a malformed config or rig file, an option out of range,
//               a camera name that is not in the rig.
//               Nothing can go on until the user changes it. UsageError, a command line that does
//               not parse, is one (the CLI exits 2 for it, 1 for the rest).
//   DataError   a file or frame is damaged or unusable: a corrupt PNG, a StreamPix frame cut
//               short, a recording whose checksum fails, an image of the wrong size for its
//               camera, a frame with no fire in view. A job that processes many frames (`run`,
//               `export`) fails that frame only and goes on.
//   IoError     the operating system refused: a file that cannot be opened, written or renamed, a
//               full disk. Output already committed is never damaged by one.
//
// Messages name the file (or the option or config key), the field and the rule broken; they are
// complete sentences without a trailing newline. Library code never prints and never exits; the
// capture path never throws across threads (drivers return statuses, see acquisition/camera.h);
// internal invariants are asserts, not exceptions.
//
// Errors from other libraries (yaml-cpp, OpenCV, OpenVDB, mrcal) are caught at the boundary that
// knows the file or field and rethrown as one of these.
#ifndef FLAMERIG_CORE_ERROR_H_
#define FLAMERIG_CORE_ERROR_H_

#include <stdexcept>
#include <string>

namespace flamerig {

class Error : public std::runtime_error {
 public:
  enum class Kind { kInput, kData, kIo, kCancelled };
  Error(Kind kind, const std::string& message) : std::runtime_error(message), kind_(kind) {}
  Kind kind() const { return kind_; }

 private:
  Kind kind_;
};

// Bad user input (options, configs, rig files, names): nothing can go on until it is changed.
class InputError : public Error {
 public:
  explicit InputError(const std::string& message) : Error(Kind::kInput, message) {}
};

// A command line that does not parse: an unknown or repeated option, a missing value, a word the
// command does not take. The CLI exits with status 2 for it.
class UsageError : public InputError {
 public:
  using InputError::InputError;
};

// A damaged or unusable file or frame. A multi-frame job fails that frame only.
class DataError : public Error {
 public:
  explicit DataError(const std::string& message) : Error(Kind::kData, message) {}
};

// The operating system refused an operation on a file or device.
class IoError : public Error {
 public:
  explicit IoError(const std::string& message) : Error(Kind::kIo, message) {}
};

// A long operation stopped because its progress callback asked it to (core/progress.h), at a safe
// point: what was committed before is whole. Thrown by jobs that have no partial result to return;
// the fits return their result with a "cancelled" termination instead.
class Cancelled : public Error {
 public:
  explicit Cancelled(const std::string& message) : Error(Kind::kCancelled, message) {}
};

// A short name of the kind, for summaries and logs: "input", "data", "io", "cancelled".
inline const char* ToString(Error::Kind kind) {
  switch (kind) {
    case Error::Kind::kInput: return "input";
    case Error::Kind::kData: return "data";
    case Error::Kind::kIo: return "io";
    case Error::Kind::kCancelled: return "cancelled";
  }
  return "?";
}

// Throws an error of the same kind as `e` whose message is `prefix` + e.what(): context added on
// the way up without losing what happened. Exceptions that are not a flamerig::Error (a library's,
// std::bad_alloc) count as `fallback`.
[[noreturn]] inline void Rethrow(const std::exception& e, const std::string& prefix,
                                 Error::Kind fallback) {
  const auto* error = dynamic_cast<const Error*>(&e);
  const std::string message = prefix + e.what();
  if (dynamic_cast<const UsageError*>(&e)) throw UsageError(message);
  switch (error ? error->kind() : fallback) {
    case Error::Kind::kInput: throw InputError(message);
    case Error::Kind::kData: throw DataError(message);
    case Error::Kind::kIo: throw IoError(message);
    case Error::Kind::kCancelled: throw Cancelled(message);
  }
  throw InputError(message);
}

}  // namespace flamerig

#endif  // FLAMERIG_CORE_ERROR_H_
