// GigE Vision action commands (GVCP ACTION_CMD): one UDP datagram that triggers every camera of a
// group at once, or, scheduled, at a given time of the PTP (IEEE 1588) clock the cameras share.
// Aravis has no API for them, so the datagram is built here.
//
// Wire format (GigE Vision 2.0, section 16; big endian), sent to UDP port 3956:
//   byte 0      0x42                      GVCP command key
//   byte 1      flags                     0x80: scheduled (action_time present); 0x01: ack wanted
//   bytes 2-3   0x0100                    ACTION_CMD
//   bytes 4-5   payload length            12, or 20 when scheduled
//   bytes 6-7   request id                non-zero
//   bytes 8-11  device key                must equal each camera's ActionDeviceKey
//   bytes 12-15 group key                 must equal the camera's ActionGroupKey
//   bytes 16-19 group mask                ANDed with the camera's ActionGroupMask (non-zero: fire)
//   bytes 20-27 action time, ns           scheduled only: the camera's PTP time to fire at
// A camera that fires answers, when asked, with an ACTION_ACK: status (2 bytes; 0 = success,
// 0x8016 = action late), 0x0101, length 0, the request id.
//
// Cameras are set up through their features (SFNC): TriggerSource = Action1, ActionDeviceKey,
// ActionGroupKey, ActionGroupMask, and PTP on (PtpEnable or GevIEEE1588) for scheduled actions.
// The host clock must follow the same PTP time (ptp4l and phc2sys), read as CLOCK_TAI.
//
// Thread safety: the functions are pure; an ActionCommandSender is used by one thread.
#ifndef FLAMERIG_ACQUISITION_GIGE_ACTION_H_
#define FLAMERIG_ACQUISITION_GIGE_ACTION_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace flamerig {

inline constexpr std::uint16_t kGvcpPort = 3956;
inline constexpr std::uint16_t kGvcpActionCmd = 0x0100;
inline constexpr std::uint16_t kGvcpActionAck = 0x0101;
inline constexpr std::uint16_t kGvcpStatusActionLate = 0x8016;

struct ActionCommand {
  std::uint32_t device_key = 0;
  std::uint32_t group_key = 0;
  std::uint32_t group_mask = 0xffffffff;
  std::optional<std::uint64_t> action_time_ns;  // scheduled: PTP time to fire at
  bool ack_required = false;
  std::uint16_t request_id = 1;  // must not be 0
};

// The datagram's bytes. Throws InputError for request id 0 or group mask 0 (a mask of
// 0 fires no camera).
std::vector<std::uint8_t> EncodeActionCommand(const ActionCommand& command);

// Parses a datagram as an ACTION_CMD (what a camera receives): nullopt when it is not one (wrong
// key, command, length).
std::optional<ActionCommand> DecodeActionCommand(const std::uint8_t* data, std::size_t size);

struct ActionAck {
  std::uint16_t status = 0;  // 0: success
  std::uint16_t ack_id = 0;  // the request id it answers
};
std::vector<std::uint8_t> EncodeActionAck(const ActionAck& ack);
// nullopt when the datagram is not an ACTION_ACK.
std::optional<ActionAck> DecodeActionAck(const std::uint8_t* data, std::size_t size);

// The current time of the PTP clock as the host follows it (CLOCK_TAI), ns.
std::uint64_t PtpNowNs();

// Sends action commands from one UDP socket (broadcast allowed) and collects acknowledgements.
class ActionCommandSender {
 public:
  // `destination`: an IPv4 address (a camera, or a subnet's broadcast address such as
  // 192.168.1.255, or 255.255.255.255); `port` 3956 for cameras. Throws IoError naming
  // the address when the socket cannot be made.
  explicit ActionCommandSender(const std::string& destination, std::uint16_t port = kGvcpPort);
  ~ActionCommandSender();
  ActionCommandSender(const ActionCommandSender&) = delete;
  ActionCommandSender& operator=(const ActionCommandSender&) = delete;

  // Sends one command under the next request id (1, 2, ... skipping 0; command.request_id is
  // replaced and returned through last_request_id()). With command.ack_required, waits up to `ack_timeout_ms` for `expected_acks` answers carrying
  // its request id and returns them (late ones included, with their status); else returns none.
  // Throws IoError when the datagram cannot be sent.
  std::vector<ActionAck> Send(ActionCommand command, int expected_acks = 0,
                              int ack_timeout_ms = 20);
  std::uint64_t sent() const { return sent_; }
  std::uint16_t last_request_id() const { return last_request_id_; }

 private:
  int socket_ = -1;
  std::string destination_;
  std::uint16_t port_;
  std::uint16_t next_request_id_ = 1;
  std::uint16_t last_request_id_ = 0;
  std::uint64_t sent_ = 0;
};

}  // namespace flamerig

#endif  // FLAMERIG_ACQUISITION_GIGE_ACTION_H_
