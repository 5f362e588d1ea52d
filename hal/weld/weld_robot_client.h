#pragma once

// The host driver of the 5-DOF weld-repair robot controller (seed 004), over Modbus TCP or RTU
// (hal::ModbusClient). Register map: hal/weld/weld_robot_registers.h, docs/weld-robot-modbus.md.
//
// Units: SI at this interface. Joints are [θ1, θ2, pz3, θ4, θ5]: rad, rad, m, rad, rad (the
// controller's joint values, without the D-H offsets of seed 004); speeds rad/s and m/s;
// durations s; welding current A, arc voltage V, wire feed speed m/s. The conversion to register
// units happens in this driver only.
//
// Lifecycle (STYLE.md, common::DeviceLifecycle): Open() -> unconfigured; Configure() reads the
// identity and limit registers -> configured (state readable); Activate() -> active (commands
// accepted); an alarm the robot reports, or a link that failed (no answer, connection lost) ->
// fault. AlarmReset() brings a faulted robot back to active. Motion and arc commands are refused
// with Errc::kNotActive unless active; Stop(), ArcOff(), AlarmReset() and ReadState() are
// allowed in every lifecycle but unconfigured.
//
// Faults at run time are std::error_code values, never exceptions:
//  - an alarm of the robot: a WeldRobotAlarmCategory code whose value is the alarm code and whose
//    message names it ("SEQUENCE GAP (weld robot alarm 2)");
//  - no answer / link lost: Errc::kTimeout / Errc::kClosed (after the ModbusClient's retries);
//  - a Modbus exception the robot answered without an alarm: the ModbusErrc code;
//  - bad arguments (a non-finite value, a target outside the limits read at Configure()):
//    Errc::kInvalidArgument, nothing sent.
// Every failure is logged with the device name, and last_error_text() says it in one line that
// starts with name().
//
// Threading: one thread at a time (the ModbusClient's rule). The cancel flag of
// StreamTrajectory() may be set from any thread.

#include <array>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include "common/clock.h"
#include "hal/drive/motor_drive.h"
#include "hal/modbus/modbus_client.h"
#include "hal/weld/weld_robot_registers.h"

namespace kinevis::hal {

// [θ1, θ2, pz3, θ4, θ5]: rad, rad, m, rad, rad.
using WeldJoints = std::array<double, weld_robot::kJointCount>;

// Alarms as error codes: value = the robot's alarm code (weld_robot::Alarm, or any other code the
// robot reports), message = its name and code, "SEQUENCE GAP (weld robot alarm 2)".
const std::error_category& WeldRobotAlarmCategory();
std::error_code WeldRobotAlarmError(uint16_t code);
namespace weld_robot {
std::error_code make_error_code(Alarm alarm);
}  // namespace weld_robot

struct WeldJointLimit {
  double min = 0.0;        // rad or m
  double max = 0.0;        // rad or m
  double max_speed = 0.0;  // rad/s or m/s, > 0
};

// Read from the identity registers by Configure().
struct WeldRobotIdentity {
  int map_version = 0;
  int joint_count = 0;
  int buffer_capacity = 0;            // segments
  double max_segment_duration = 0.0;  // s
  uint32_t serial_number = 0;
  std::array<WeldJointLimit, weld_robot::kJointCount> joints{};
  double max_current = 0.0;          // A
  double max_voltage = 0.0;          // V
  double max_wire_feed_speed = 0.0;  // m/s
};

struct WeldParameters {
  double current = 0.0;          // welding current, A, 0..identity().max_current
  double voltage = 0.0;          // arc voltage, V, 0..identity().max_voltage
  double wire_feed_speed = 0.0;  // m/s, 0..identity().max_wire_feed_speed
};

struct WeldRobotState {
  WeldJoints joints{};  // actual joints, SI
  weld_robot::MotionState motion = weld_robot::MotionState::kIdle;
  uint16_t motion_raw = 0;  // the register as read (for a state this driver does not know)
  int buffer_level = 0;     // segments accepted and not completed, the executing one included
  int buffer_capacity = 0;
  uint16_t alarm_code = 0;          // 0 = none
  const char* alarm_name = "NONE";  // weld_robot::AlarmName(alarm_code)
  uint32_t alarm_sequence = 0;      // sequence number of the segment that raised it (0: none)
  bool arc_enabled = false;         // ARC ON commanded and not revoked
  bool arc_on = false;              // the arc burns now
  uint32_t last_sequence = 0;       // last segment accepted
  uint32_t completed_sequence = 0;  // last segment completed
  WeldParameters weld;              // set-points in force

  bool alarm() const { return alarm_code != 0; }
  // Motion stopped and arc off: what Stop() and every fault path leave behind.
  bool safe() const { return motion != weld_robot::MotionState::kMoving && !arc_on; }
};

// One segment of a joint trajectory: the robot moves linearly in joint space from the previous
// target (or from where it stands, for the first) to `joints` in `duration`.
struct WeldTrajectoryPoint {
  WeldJoints joints{};    // target, SI, within the joint limits
  double duration = 0.0;  // s, identity().max_segment_duration >= duration >= 0.001 (rounded to ms)
  bool arc_on = false;    // the arc burns during this segment (with ARC ON and valid set-points)
};

struct WeldStreamProgress {
  size_t total = 0;      // segments in the trajectory
  size_t sent = 0;       // accepted by the robot
  size_t executed = 0;   // completed by the robot
  int buffer_level = 0;  // as last read
  int buffer_capacity = 0;
  WeldJoints joints{};  // actual joints as last read
  bool arc_on = false;
};
using WeldStreamProgressCallback = std::function<void(const WeldStreamProgress&)>;

struct WeldStreamOptions {
  // Check every target and speed against the limits read at Configure() before sending
  // anything (Errc::kInvalidArgument naming the segment and joint). Off: the robot judges, and
  // raises an alarm on the first bad segment.
  bool check_limits = true;
  // Bound on the whole call. 0: the sum of the segment durations plus `margin`.
  std::chrono::milliseconds timeout{0};
  std::chrono::milliseconds margin{5000};
  // A request that needed a retry or a reconnect means the link was interrupted: the stream is
  // aborted (Errc::kClosed) and the robot stopped, rather than welding on after a gap in
  // supervision. Off: carry on when the ModbusClient's retry succeeded.
  bool abort_on_link_interruption = true;
};

struct WeldStreamReport {
  size_t total = 0;
  size_t sent = 0;                 // segments the robot accepted
  size_t executed = 0;             // segments the robot reported completed
  int max_buffer_level = 0;        // highest level the host caused or saw (<= capacity)
  uint64_t buffer_full_waits = 0;  // polls that found no free slot
  uint16_t alarm_code = 0;         // the alarm that ended the stream, 0 if none
  // After a failure: STOP was acknowledged and the state read back shows motion stopped, arc off.
  bool safe_state_confirmed = false;
  std::string message;  // empty on success; else last_error_text()
  common::Duration elapsed{0};
};

struct WeldRobotClientCounters {
  uint64_t segments_sent = 0;
  uint64_t status_reads = 0;
  uint64_t buffer_full_waits = 0;
  uint64_t alarms = 0;       // alarms observed (each new one once)
  uint64_t link_faults = 0;  // operations that failed with a timeout or a lost link
  uint64_t safe_stops = 0;   // STOPs sent by a fault path
};

class WeldRobotClient {
 public:
  struct Options {
    std::string name = "weld-robot";            // the device name; name() appends the backend
    common::Clock* clock = nullptr;             // for waiting on the buffer; nullptr: SteadyClock
    std::chrono::milliseconds poll_period{10};  // status poll while the buffer is full, > 0
  };

  // Opens the Modbus link (ModbusClient::Open: throws ConfigError for a bad backend string,
  // HalError when it cannot connect) -> unconfigured.
  static std::unique_ptr<WeldRobotClient> Open(std::string_view backend, Options options);
  static std::unique_ptr<WeldRobotClient> Open(std::string_view backend) {
    return Open(backend, Options());
  }
  // Over an open ModbusClient. Throws ConfigError for bad options.
  WeldRobotClient(std::unique_ptr<ModbusClient> modbus, Options options);
  ~WeldRobotClient();
  WeldRobotClient(const WeldRobotClient&) = delete;
  WeldRobotClient& operator=(const WeldRobotClient&) = delete;

  // "weld-robot (modbus-tcp:127.0.0.1:1502)": in every log line and error.
  const std::string& name() const { return name_; }
  common::DeviceLifecycle lifecycle() const { return lifecycle_; }

  // Set-up: reads and checks the identity and limit registers -> configured. Throws HalError
  // naming the device, "configure" and the cause (no answer, wrong magic, unsupported map
  // version, a joint count other than 5, inconsistent limits).
  void Configure();
  // Valid after Configure().
  const WeldRobotIdentity& identity() const { return identity_; }

  // configured -> active. Reads the state first: an active alarm returns its code and leaves the
  // driver in fault (AlarmReset() then). Errc::kNotActive before Configure().
  std::error_code Activate();

  // One status read (one 0x04 request). Observing an alarm, or failing on the link, -> fault.
  std::error_code ReadState(WeldRobotState* state);

  // Writes the three set-points in one 0x10 request. Errc::kInvalidArgument when a value is
  // negative, not finite or above the identity's maximum.
  std::error_code SetWeldParameters(const WeldParameters& parameters);
  // Arc enable. The arc then burns during segments flagged arc-on (the interlock, see
  // weld_robot_registers.h). Errc::kInvalidArgument when a weld set-point is zero; the alarm's
  // code when one is active.
  std::error_code ArcOn();
  // Arc disable; the arc goes out at once.
  std::error_code ArcOff();
  // The safe state: motion stops where it is, the buffer is cleared, arc off and disabled.
  // Confirms it by reading the state back (Errc::kDeviceFault if the robot still moves or burns).
  std::error_code Stop();
  // Clears the robot's alarm; fault -> active (configured stays configured). Returns the alarm's
  // code when the robot keeps it.
  std::error_code AlarmReset();

  // Streams `points` to the robot and waits until it has executed them all (or failed).
  // Flow control: before writing, the host reads the buffer level and writes at most
  // capacity - level segments (the robot only consumes meanwhile, so the buffer never
  // overflows); when it is full the host polls every poll_period. Each segment is one 0x10
  // request; sequence numbers continue from the robot's last accepted one.
  // `progress` (may be empty) is called on this thread after every status read. `cancel` (may be
  // null) is checked before every request; when set, the robot is stopped and the call returns
  // std::errc::operation_canceled.
  // Failures: the robot's alarm (the stream stops, its name and code are reported), a link that
  // failed or was interrupted (Errc::kTimeout / kClosed), Errc::kDeviceFault when the robot
  // discarded buffered segments without an alarm (a STOP from elsewhere), Errc::kTimeout when
  // the whole call exceeds its bound, Errc::kNotActive unless active, Errc::kInvalidArgument for
  // bad points (nothing sent). After any failure that follows the first write the driver sends STOP
  // (the ModbusClient reconnects for it if needed) and reads the state back to confirm the safe
  // state; the outcome is in report->safe_state_confirmed. Alarms and link failures -> fault.
  std::error_code StreamTrajectory(const std::vector<WeldTrajectoryPoint>& points,
                                   const WeldStreamProgressCallback& progress,
                                   const std::atomic<bool>* cancel,
                                   const WeldStreamOptions& options = WeldStreamOptions(),
                                   WeldStreamReport* report = nullptr);

  // The last failure in one line, starting with name() ("weld-robot (modbus-tcp:...): stream:
  // alarm SEQUENCE GAP (code 2) raised by sequence 41; 37 of 200 segments executed"); empty if
  // none.
  const std::string& last_error_text() const { return last_error_text_; }
  WeldRobotClientCounters counters() const { return counters_; }
  ModbusClient& modbus() { return *modbus_; }

 private:
  std::error_code RequireActive(const char* operation);
  std::error_code ReadStateRaw(WeldRobotState* state);
  std::error_code SendCommand(weld_robot::Command command);
  // Records a failure: text, log line, lifecycle (alarm or link failure -> fault).
  std::error_code Fail(std::error_code ec, const std::string& operation, const std::string& cause);
  // After a refused request: reads the state and returns the robot's alarm if one is active,
  // otherwise `ec`.
  std::error_code ExplainRefusal(std::error_code ec, WeldRobotState* state);
  // STOP and a state read-back; true when the robot confirms the safe state.
  bool SafeStop();
  uint64_t LinkInterruptions() const;

  std::unique_ptr<ModbusClient> modbus_;
  Options options_;
  common::Clock* clock_;
  std::string name_;
  common::DeviceLifecycle lifecycle_ = common::DeviceLifecycle::kUnconfigured;
  WeldRobotIdentity identity_;
  uint16_t last_alarm_seen_ = 0;
  std::string last_error_text_;
  WeldRobotClientCounters counters_;
};

}  // namespace kinevis::hal

namespace std {
template <>
struct is_error_code_enum<kinevis::hal::weld_robot::Alarm> : true_type {};
}  // namespace std
