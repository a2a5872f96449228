// GigE Vision action commands: the datagram's bytes against the layout of the GigE Vision 2.0
// specification (written out by hand below), the acknowledgement, a round trip over loopback UDP
// to a fake device, and the capture daemon scheduling them in PTP mode.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <thread>

#include "core/error.h"
#include "acquisition/capture.h"
#include "acquisition/gige_action.h"

namespace flamerig {
namespace {

TEST(ActionCommand, UnscheduledBytesFollowTheSpecification) {
  ActionCommand c;
  c.device_key = 0x12345678;
  c.group_key = 0x00000001;
  c.group_mask = 0xffffffff;
  c.ack_required = true;
  c.request_id = 0x0102;
  const std::vector<std::uint8_t> want = {
      0x42, 0x01,              // key, flags: acknowledge
      0x01, 0x00,              // ACTION_CMD
      0x00, 0x0c,              // payload: 12 bytes
      0x01, 0x02,              // request id
      0x12, 0x34, 0x56, 0x78,  // device key
      0x00, 0x00, 0x00, 0x01,  // group key
      0xff, 0xff, 0xff, 0xff,  // group mask
  };
  EXPECT_EQ(EncodeActionCommand(c), want);
}

TEST(ActionCommand, ScheduledBytesCarryTheActionTime) {
  ActionCommand c;
  c.device_key = 0xa1b2c3d4;
  c.group_key = 0x00000020;
  c.group_mask = 0x00000003;
  c.action_time_ns = 0x0123456789abcdefULL;
  c.request_id = 7;
  const std::vector<std::uint8_t> want = {
      0x42, 0x80, 0x01, 0x00, 0x00, 0x14, 0x00, 0x07,  // scheduled, no ack, 20 bytes, id 7
      0xa1, 0xb2, 0xc3, 0xd4, 0x00, 0x00, 0x00, 0x20, 0x00, 0x00,
      0x00, 0x03, 0x01, 0x23, 0x45, 0x67, 0x89, 0xab, 0xcd, 0xef,  // action time, big endian
  };
  const auto bytes = EncodeActionCommand(c);
  EXPECT_EQ(bytes, want);
  const auto back = DecodeActionCommand(bytes.data(), bytes.size());
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(back->device_key, c.device_key);
  EXPECT_EQ(back->group_key, c.group_key);
  EXPECT_EQ(back->group_mask, c.group_mask);
  EXPECT_EQ(back->action_time_ns, c.action_time_ns);
  EXPECT_EQ(back->request_id, 7);
  EXPECT_FALSE(back->ack_required);
}

TEST(ActionCommand, MalformedDatagramsAreNotCommands) {
  ActionCommand c;
  auto bytes = EncodeActionCommand(c);
  EXPECT_FALSE(DecodeActionCommand(bytes.data(), bytes.size() - 1).has_value());  // cut short
  auto wrong_key = bytes;
  wrong_key[0] = 0x43;
  EXPECT_FALSE(DecodeActionCommand(wrong_key.data(), wrong_key.size()).has_value());
  auto read_register = bytes;
  read_register[3] = 0x80;  // 0x0080: READREG, not an action
  EXPECT_FALSE(DecodeActionCommand(read_register.data(), read_register.size()).has_value());
  auto flagged_scheduled = bytes;
  flagged_scheduled[1] = 0x80;  // says scheduled but carries 12 bytes
  EXPECT_FALSE(DecodeActionCommand(flagged_scheduled.data(), flagged_scheduled.size()).has_value());
  c.request_id = 0;
  EXPECT_THROW(EncodeActionCommand(c), InputError);
  c.request_id = 1;
  c.group_mask = 0;
  EXPECT_THROW(EncodeActionCommand(c), InputError);
}

TEST(ActionAck, BytesAndParsing) {
  const auto bytes = EncodeActionAck(ActionAck{kGvcpStatusActionLate, 5});
  const std::vector<std::uint8_t> want = {0x80, 0x16, 0x01, 0x01, 0x00, 0x00, 0x00, 0x05};
  EXPECT_EQ(bytes, want);
  const auto ack = DecodeActionAck(bytes.data(), bytes.size());
  ASSERT_TRUE(ack.has_value());
  EXPECT_EQ(ack->status, kGvcpStatusActionLate);
  EXPECT_EQ(ack->ack_id, 5);
  const std::vector<std::uint8_t> write_ack = {0x00, 0x00, 0x00, 0x83, 0x00, 0x04, 0x00, 0x05};
  EXPECT_FALSE(DecodeActionAck(write_ack.data(), write_ack.size()).has_value());
}

// A device on loopback: answers commands whose keys and mask match its own, as a camera does.
class FakeActionDevice {
 public:
  FakeActionDevice(std::uint32_t device_key, std::uint32_t group_key, std::uint32_t group_mask)
      : device_key_(device_key), group_key_(group_key), group_mask_(group_mask) {
    socket_ = ::socket(AF_INET, SOCK_DGRAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = 0;
    EXPECT_EQ(::bind(socket_, reinterpret_cast<sockaddr*>(&a), sizeof a), 0);
    socklen_t len = sizeof a;
    ::getsockname(socket_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    thread_ = std::thread([this] { Serve(); });
  }
  ~FakeActionDevice() {
    stop_ = true;
    thread_.join();
    ::close(socket_);
  }
  std::uint16_t port() const { return port_; }
  int fired() const { return fired_; }
  std::vector<ActionCommand> received() {
    std::lock_guard<std::mutex> lock(mutex_);
    return received_;
  }

 private:
  void Serve() {
    while (!stop_) {
      pollfd p{socket_, POLLIN, 0};
      if (::poll(&p, 1, 20) <= 0) continue;
      std::uint8_t buffer[128];
      sockaddr_in from{};
      socklen_t len = sizeof from;
      const ssize_t n =
          ::recvfrom(socket_, buffer, sizeof buffer, 0, reinterpret_cast<sockaddr*>(&from), &len);
      const auto c = DecodeActionCommand(buffer, n > 0 ? static_cast<std::size_t>(n) : 0);
      if (!c) continue;
      {
        std::lock_guard<std::mutex> lock(mutex_);
        received_.push_back(*c);
      }
      // The specification's rule: keys equal and the masks share a bit.
      if (c->device_key != device_key_ || c->group_key != group_key_ ||
          (c->group_mask & group_mask_) == 0)
        continue;
      ++fired_;
      if (c->ack_required) {
        const auto ack = EncodeActionAck(ActionAck{0, c->request_id});
        ::sendto(socket_, ack.data(), ack.size(), 0, reinterpret_cast<sockaddr*>(&from), len);
      }
    }
  }
  std::uint32_t device_key_, group_key_, group_mask_;
  int socket_ = -1;
  std::uint16_t port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<int> fired_{0};
  std::mutex mutex_;
  std::vector<ActionCommand> received_;
  std::thread thread_;
};

TEST(ActionCommandSender, AMatchingDeviceFiresAndAcknowledges) {
  FakeActionDevice device(0x11223344, 0x5, 0x1);
  ActionCommandSender sender("127.0.0.1", device.port());
  ActionCommand c;
  c.device_key = 0x11223344;
  c.group_key = 0x5;
  c.group_mask = 0x3;
  c.ack_required = true;
  const auto acks = sender.Send(c, 1, 1000);
  ASSERT_EQ(acks.size(), 1u);
  EXPECT_EQ(acks[0].status, 0);
  EXPECT_EQ(acks[0].ack_id, sender.last_request_id());
  // Another device key: the device ignores it, so no acknowledgement comes.
  c.device_key = 0x99;
  EXPECT_TRUE(sender.Send(c, 1, 100).empty());
  EXPECT_EQ(device.fired(), 1);
  EXPECT_EQ(sender.sent(), 2u);
  EXPECT_NE(sender.last_request_id(), acks[0].ack_id);  // every command its own id
  EXPECT_THROW(ActionCommandSender("not-an-address"), std::runtime_error);
}

// The daemon in PTP mode schedules one action command per trigger period, lead_ms ahead of the
// PTP clock, with the configured keys.
TEST(CaptureDaemon, PtpModeSchedulesActionCommands) {
  FakeActionDevice device(7, 3, 1);
  char dir_template[] = "/tmp/flamerig_action_XXXXXX";
  const std::string dir = ::mkdtemp(dir_template);
  const std::string yaml = "data_dir: " + dir +
                           "\nsync: ptp\ntrigger_rate_hz: 20\npretrigger_seconds: 0\n"
                           "action: {device_key: 7, group_key: 3, group_mask: 1, lead_ms: 30,"
                           " destination: 127.0.0.1, port: " +
                           std::to_string(device.port()) +
                           "}\ncameras:\n  - {name: a, width: 32, height: 24}\n";
  const CaptureConfig config = CaptureConfig::Parse(yaml, "test");
  SystemClock clock;
  CaptureDaemon daemon(config, MakeCameras(config, {&clock, nullptr}), &clock, nullptr);
  daemon.Start();
  std::this_thread::sleep_for(std::chrono::milliseconds(1000));
  const std::uint64_t sent = daemon.status().action_commands;
  daemon.Stop();
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  const auto got = device.received();
  EXPECT_GE(sent, 15u);  // 20 Hz for a second, on a loaded host
  EXPECT_LE(sent, 21u);
  EXPECT_GE(got.size() + 1, sent);  // loopback loses nothing (the last may be in flight)
  EXPECT_EQ(device.fired(), static_cast<int>(got.size()));
  const std::uint64_t now = PtpNowNs();
  for (std::size_t i = 0; i < got.size(); ++i) {
    ASSERT_TRUE(got[i].action_time_ns.has_value());
    EXPECT_LT(*got[i].action_time_ns, now + 30'000'000);  // scheduled at most lead_ms ahead
    EXPECT_GT(*got[i].action_time_ns, now - 2'000'000'000ULL);
    if (i > 0) {
      EXPECT_GT(got[i].request_id, got[i - 1].request_id);
      // One trigger period apart, give or take the trigger thread's scheduling.
      const double gap_ms = (*got[i].action_time_ns - *got[i - 1].action_time_ns) / 1e6;
      EXPECT_GT(gap_ms, 0.75 * 50);
      EXPECT_LT(gap_ms, 150);
    }
  }
  std::filesystem::remove_all(dir);
}

TEST(CaptureConfig, ActionCommandsNeedPtpAndAMask) {
  auto error = [](const std::string& yaml) {
    try {
      CaptureConfig::Parse(yaml + "cameras: [{name: a}]\n", "rig.yaml");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("(no error)");
  };
  EXPECT_NE(error("sync: software-trigger\naction: {device_key: 1}\n").find("needs sync: ptp"),
            std::string::npos);
  EXPECT_NE(error("sync: ptp\naction: {group_mask: 0}\n").find("group_mask"), std::string::npos);
  EXPECT_NE(error("sync: ptp\naction: {device_key: -1}\n").find("device_key"), std::string::npos);
  const CaptureConfig hex = CaptureConfig::Parse(
      "sync: ptp\naction: {device_key: 0x1A2B, group_mask: 0xffffffff}\ncameras: [{name: a}]\n",
      "rig.yaml");
  EXPECT_EQ(hex.action.device_key, 0x1a2bu);
  EXPECT_EQ(hex.action.group_mask, 0xffffffffu);
  EXPECT_NE(error("sync: ptp\naction: {group_key: 0x100000000}\n").find("group_key"),
            std::string::npos);
  EXPECT_NE(error("sync: ptp\naction: {colour: red}\n").find("unknown key 'colour'"),
            std::string::npos);
}

}  // namespace
}  // namespace flamerig
