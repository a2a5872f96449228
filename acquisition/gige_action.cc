#include "acquisition/gige_action.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <stdexcept>

#include "core/error.h"

namespace flamerig {

namespace {

constexpr std::uint8_t kGvcpKey = 0x42;
constexpr std::uint8_t kFlagScheduled = 0x80;
constexpr std::uint8_t kFlagAckRequired = 0x01;

void Put16(std::vector<std::uint8_t>* b, std::uint16_t v) {
  b->push_back(static_cast<std::uint8_t>(v >> 8));
  b->push_back(static_cast<std::uint8_t>(v));
}
void Put32(std::vector<std::uint8_t>* b, std::uint32_t v) {
  Put16(b, static_cast<std::uint16_t>(v >> 16));
  Put16(b, static_cast<std::uint16_t>(v));
}
std::uint16_t Get16(const std::uint8_t* p) { return static_cast<std::uint16_t>(p[0] << 8 | p[1]); }
std::uint32_t Get32(const std::uint8_t* p) {
  return static_cast<std::uint32_t>(Get16(p)) << 16 | Get16(p + 2);
}

}  // namespace

std::vector<std::uint8_t> EncodeActionCommand(const ActionCommand& c) {
  if (c.request_id == 0) throw InputError("action command: request id 0 is reserved");
  if (c.group_mask == 0)
    throw InputError("action command: a group mask of 0 fires no camera");
  std::vector<std::uint8_t> b;
  b.reserve(28);
  b.push_back(kGvcpKey);
  b.push_back(static_cast<std::uint8_t>((c.action_time_ns ? kFlagScheduled : 0) |
                                        (c.ack_required ? kFlagAckRequired : 0)));
  Put16(&b, kGvcpActionCmd);
  Put16(&b, c.action_time_ns ? 20 : 12);
  Put16(&b, c.request_id);
  Put32(&b, c.device_key);
  Put32(&b, c.group_key);
  Put32(&b, c.group_mask);
  if (c.action_time_ns) {
    Put32(&b, static_cast<std::uint32_t>(*c.action_time_ns >> 32));
    Put32(&b, static_cast<std::uint32_t>(*c.action_time_ns));
  }
  return b;
}

std::optional<ActionCommand> DecodeActionCommand(const std::uint8_t* d, std::size_t n) {
  if (n < 20 || d[0] != kGvcpKey || Get16(d + 2) != kGvcpActionCmd) return std::nullopt;
  const bool scheduled = d[1] & kFlagScheduled;
  const std::uint16_t length = Get16(d + 4);
  if (length != (scheduled ? 20 : 12) || n < 8u + length) return std::nullopt;
  ActionCommand c;
  c.ack_required = d[1] & kFlagAckRequired;
  c.request_id = Get16(d + 6);
  c.device_key = Get32(d + 8);
  c.group_key = Get32(d + 12);
  c.group_mask = Get32(d + 16);
  if (scheduled) c.action_time_ns = static_cast<std::uint64_t>(Get32(d + 20)) << 32 | Get32(d + 24);
  return c;
}

std::vector<std::uint8_t> EncodeActionAck(const ActionAck& a) {
  std::vector<std::uint8_t> b;
  Put16(&b, a.status);
  Put16(&b, kGvcpActionAck);
  Put16(&b, 0);
  Put16(&b, a.ack_id);
  return b;
}

std::optional<ActionAck> DecodeActionAck(const std::uint8_t* d, std::size_t n) {
  if (n < 8 || Get16(d + 2) != kGvcpActionAck || Get16(d + 4) != 0) return std::nullopt;
  return ActionAck{Get16(d), Get16(d + 6)};
}

std::uint64_t PtpNowNs() {
  timespec ts{};
  clock_gettime(CLOCK_TAI, &ts);
  return static_cast<std::uint64_t>(ts.tv_sec) * 1'000'000'000ULL +
         static_cast<std::uint64_t>(ts.tv_nsec);
}

ActionCommandSender::ActionCommandSender(const std::string& destination, std::uint16_t port)
    : destination_(destination), port_(port) {
  in_addr addr{};
  if (inet_pton(AF_INET, destination.c_str(), &addr) != 1)
    throw InputError("action commands: '" + destination + "' is not an IPv4 address");
  socket_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
  if (socket_ < 0)
    throw IoError("action commands to " + destination +
                             ": socket: " + std::strerror(errno));
  const int on = 1;
  setsockopt(socket_, SOL_SOCKET, SO_BROADCAST, &on, sizeof on);
}

ActionCommandSender::~ActionCommandSender() {
  if (socket_ >= 0) ::close(socket_);
}

std::vector<ActionAck> ActionCommandSender::Send(ActionCommand command, int expected_acks,
                                                 int ack_timeout_ms) {
  command.request_id = next_request_id_;
  last_request_id_ = next_request_id_;
  if (++next_request_id_ == 0) next_request_id_ = 1;
  const std::vector<std::uint8_t> bytes = EncodeActionCommand(command);
  sockaddr_in to{};
  to.sin_family = AF_INET;
  to.sin_port = htons(port_);
  inet_pton(AF_INET, destination_.c_str(), &to.sin_addr);
  if (::sendto(socket_, bytes.data(), bytes.size(), 0, reinterpret_cast<sockaddr*>(&to),
               sizeof to) != static_cast<ssize_t>(bytes.size()))
    throw IoError("action command to " + destination_ + ":" + std::to_string(port_) +
                             ": " + std::strerror(errno));
  ++sent_;
  std::vector<ActionAck> acks;
  if (!command.ack_required || expected_acks <= 0) return acks;
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::milliseconds(ack_timeout_ms);
  while (static_cast<int>(acks.size()) < expected_acks) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
                          deadline - std::chrono::steady_clock::now())
                          .count();
    if (left <= 0) break;
    pollfd p{socket_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(left)) <= 0) break;
    std::uint8_t buffer[64];
    const ssize_t n = ::recv(socket_, buffer, sizeof buffer, 0);
    if (n <= 0) continue;
    const auto ack = DecodeActionAck(buffer, static_cast<std::size_t>(n));
    if (ack && ack->ack_id == command.request_id) acks.push_back(*ack);  // stale ones dropped
  }
  return acks;
}

}  // namespace flamerig
