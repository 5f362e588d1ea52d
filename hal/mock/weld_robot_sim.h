#pragma once

// A simulated controller of the 5-DOF weld-repair robot (seed 004): a real Modbus server
// (hal::ModbusServer) on loopback TCP or on a pseudo-terminal (RTU) that serves the register map
// of hal/weld/weld_robot_registers.h and executes the trajectory stream written to it, exactly as
// docs/weld-robot-modbus.md specifies the real controller.
//
// Motion: buffered segments are executed one after the other, each a linear interpolation in
// joint space from the previous target to its target over its duration; the robot stops dead
// (no deceleration ramp) on STOP or an alarm, where it is.
//
// Checks on every segment write, in this order, each raising the alarm named (the write is then
// answered with ILLEGAL DATA VALUE, exception 3, and nothing of it is kept):
//   the buffer is full                                 -> BUFFER OVERFLOW
//   sequence number != last accepted + 1               -> SEQUENCE GAP
//     (except the first segment after power-on, STOP or ALARM RESET, which may carry any number;
//      and a repetition of the last accepted segment, identical in every register, which is
//      acknowledged and ignored, so that a request retried after a lost answer is harmless)
//   duration outside 1..max_segment_duration ms, or unknown flag bits -> BAD SEGMENT
//   a target outside its joint's limits                -> TARGET OUT OF RANGE
//   |target - previous target| * 1000 > speed limit * duration_ms, for any joint
//     (previous target: the last buffered segment's, or the actual joints when the buffer is
//      empty; integer register units, exact)      -> SPEED LIMIT
// Any alarm: motion stops, the arc goes out and is disabled, the buffer is cleared; segment
// writes and ARC ON are refused with SERVER DEVICE FAILURE (exception 4) until ALARM RESET.
// Other refusals (no alarm): a write to the segment block that is not one 0x10 request of
// exactly its 14 registers (ILLEGAL DATA ADDRESS, or ILLEGAL FUNCTION for 0x06/0x16/0x17), an
// unknown command or a set-point above its limit (ILLEGAL DATA VALUE), ARC ON while a set-point
// is zero (ILLEGAL DATA VALUE), writes elsewhere (ILLEGAL DATA ADDRESS), 0x16/0x17 (ILLEGAL
// FUNCTION). There are no coils or discrete inputs.
//
// Time: the motion executor runs on its own thread by default (Options::run_executor), calling
// Update() every Options::tick on Options::clock (SteadyClock when null). For deterministic
// tests turn the thread off and drive the simulator yourself: Step(dt) advances it by dt, and
// Update() advances it to clock->Now() (advance a SimulatedClock, then Update()).
//
// Units: Options and State are SI (rad, m, rad/s, m/s, s, A, V, m/s); the register edge converts.
//
// Threads: all state lives under the ModbusServer's register mutex (the server thread runs the
// hooks under it), so every public method is thread-safe and sees each request wholly applied
// or not at all.

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/clock.h"
#include "hal/modbus/modbus_server.h"
#include "hal/serial/pty_pair.h"
#include "hal/weld/weld_robot_registers.h"

namespace kinevis::hal {

class WeldRobotSim {
 public:
  struct JointLimit {
    double min;        // rad or m
    double max;        // rad or m
    double max_speed;  // rad/s or m/s, > 0
  };

  struct Options {
    // Joint limits and speed limits of [θ1, θ2, pz3, θ4, θ5]. Defaults: θ1 ±170°, θ2 ±120°,
    // pz3 0..500 mm, θ4 ±180°, θ5 ±120°; 90°/s for the rotary joints, 50 mm/s for pz3 — the
    // same as robots::Weld5Model::Seed() and robots/weld5/weld5.yaml (a test checks all three).
    std::array<JointLimit, weld_robot::kJointCount> joints = DefaultJointLimits();
    // Where the robot stands at power-on (within the limits).
    std::array<double, weld_robot::kJointCount> initial_joints = {0.0, 0.0, 0.05, 0.0, 0.0};
    int buffer_capacity = 16;            // segments, 1..1000
    double max_segment_duration = 60.0;  // s, 0.001..65.535
    double max_current = 400.0;          // A, largest current set-point, 0..6553.5
    double max_voltage = 45.0;           // V, 0..6553.5
    double max_wire_feed_speed = 0.4;    // m/s (24 m/min), 0..6.5535
    uint32_t serial_number = 4;
    int unit = 1;                         // Modbus unit id, 1..247
    bool run_executor = true;             // the real-time executor thread
    std::chrono::milliseconds tick{2};    // executor period, > 0
    common::Clock* clock = nullptr;       // executor's clock; nullptr: SteadyClock
    std::string name = "weld-robot-sim";  // log prefix
  };

  static std::array<JointLimit, weld_robot::kJointCount> DefaultJointLimits();

  // What the robot is doing, in SI.
  struct State {
    std::array<double, weld_robot::kJointCount> joints{};  // actual
    weld_robot::MotionState motion = weld_robot::MotionState::kIdle;
    uint16_t alarm_code = 0;
    uint32_t alarm_sequence = 0;
    int buffer_level = 0;
    bool arc_enabled = false;
    bool arc_on = false;
    uint32_t last_sequence = 0;
    uint32_t completed_sequence = 0;
    double current = 0.0;          // A
    double voltage = 0.0;          // V
    double wire_feed_speed = 0.0;  // m/s
  };

  struct Statistics {
    uint64_t segments_accepted = 0;
    uint64_t segments_completed = 0;
    uint64_t duplicates_ignored = 0;  // repeated last segments acknowledged and ignored
    uint64_t writes_refused = 0;      // requests answered with an exception by this simulator
    uint64_t alarms_raised = 0;
    int max_buffer_level = 0;   // high-water mark of the buffer level
    uint64_t arc_segments = 0;  // segments completed with the arc burning throughout
    double arc_time = 0.0;      // s the arc burned
  };

  // Serves Modbus TCP on host:port (port 0: ephemeral). Throws ConfigError for bad options,
  // HalError when it cannot listen.
  static std::unique_ptr<WeldRobotSim> ListenTcp(const std::string& host, int port,
                                                 const Options& options);
  static std::unique_ptr<WeldRobotSim> ListenTcp(const std::string& host, int port) {
    return ListenTcp(host, port, Options());
  }
  // Serves Modbus RTU (115200 bit/s, 8E1 in the backend string) on a new pty pair; the host opens
  // backend()'s device. link_path (may be empty) gets a symbolic link to the pty, removed again
  // on destruction. Throws ConfigError, HalError.
  static std::unique_ptr<WeldRobotSim> ServeRtu(const Options& options,
                                                const std::string& link_path = "");

  // Stops the executor and the server.
  ~WeldRobotSim();
  WeldRobotSim(const WeldRobotSim&) = delete;
  WeldRobotSim& operator=(const WeldRobotSim&) = delete;

  // The backend string that reaches the simulator ("modbus-tcp:127.0.0.1:40123",
  // "modbus-rtu:/dev/pts/7@115200,8E1").
  const std::string& backend() const { return server_->backend(); }
  ModbusServer& server() { return *server_; }
  const Options& options() const { return options_; }

  // Advances the simulation by dt (>= 0): motion, segment completion, arc.
  void Step(common::Duration dt);
  // Advances the simulation to options.clock->Now() (by the time since the previous Update(), or
  // since construction). The executor thread calls this every tick.
  void Update();

  State state() const;
  Statistics statistics() const;
  // Sequence numbers of the segments completed, in order of completion (the last 100000).
  std::vector<uint32_t> completed_sequences() const;

  // Fault injection.
  // Closes every TCP connection (ModbusServer::DropConnections); returns how many. RTU: 0.
  int DropLink();
  // Leaves every request unanswered for `duration` (the motion executor keeps running).
  void StopAnswering(std::chrono::milliseconds duration);
  void ResumeAnswering();
  // Raises alarm `code` (!= 0) as if the cell had: motion stops, arc off, buffer cleared.
  void RaiseAlarm(uint16_t code);

 private:
  struct Segment {
    uint32_t sequence = 0;
    std::array<int32_t, weld_robot::kJointCount> target{};  // register units
    std::array<int32_t, weld_robot::kJointCount> start{};   // where it starts
    uint16_t duration_ms = 0;
    uint16_t flags = 0;
    int64_t elapsed_ns = 0;
    std::array<uint16_t, weld_robot::kSegmentRegisters> raw{};  // as written, for duplicates
  };

  WeldRobotSim(const Options& options, std::unique_ptr<PtyPair> pty);
  void Start(std::unique_ptr<ModbusServer> server);
  void ExecutorLoop();

  // Everything below runs under the server's register mutex.
  ModbusErrc OnRequest(const ModbusRequest& request);
  ModbusErrc OnSegment(const uint16_t* values);
  ModbusErrc OnCommand(uint16_t command);
  ModbusErrc OnSetPoints(int address, int count, const uint16_t* values);
  void StepLocked(int64_t dt_ns);
  void RaiseAlarmLocked(uint16_t code, uint32_t sequence);
  void StopMotionLocked();
  void UpdateArcLocked();
  void PublishLocked(ModbusRegisterMap& map) const;
  void Publish();
  void WriteIdentity(ModbusRegisterMap& map) const;

  const Options options_;
  common::Clock* const clock_;
  std::unique_ptr<PtyPair> pty_;  // RTU only; outlives server_
  std::unique_ptr<ModbusServer> server_;

  // Limits in register units.
  std::array<int32_t, weld_robot::kJointCount> min_{};
  std::array<int32_t, weld_robot::kJointCount> max_{};
  std::array<int64_t, weld_robot::kJointCount> speed_{};
  uint16_t max_duration_ms_ = 0;
  uint16_t max_current_ = 0, max_voltage_ = 0, max_wire_feed_ = 0;

  // Guarded by the server's register mutex.
  std::array<int32_t, weld_robot::kJointCount> joints_{};  // actual, register units
  std::deque<Segment> buffer_;
  bool stream_open_ = false;  // false: the next segment may carry any sequence number
  std::array<uint16_t, weld_robot::kSegmentRegisters> last_raw_{};
  uint32_t last_sequence_ = 0;
  uint32_t completed_sequence_ = 0;
  uint16_t alarm_ = 0;
  uint32_t alarm_sequence_ = 0;
  bool arc_enabled_ = false;
  bool arc_on_ = false;
  uint16_t current_ = 0, voltage_ = 0, wire_feed_ = 0;  // register units
  common::Duration last_update_{0};
  Statistics stats_;
  std::deque<uint32_t> completed_log_;

  std::atomic<bool> stop_{false};
  std::thread executor_;
};

}  // namespace kinevis::hal
