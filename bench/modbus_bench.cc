// Modbus TCP register round trips on loopback: kinevis' ModbusClient against its ModbusServer,
// both over libmodbus, one request in flight at a time. items/s is requests per second.
//
//   build-*/bench/modbus_bench --benchmark_min_time=0.5

#include <benchmark/benchmark.h>

#include <array>
#include <cstdint>
#include <memory>
#include <string>

#include "hal/modbus/modbus_client.h"
#include "hal/modbus/modbus_server.h"

namespace kinevis::hal {
namespace {

constexpr int kCount = 10;

struct Loopback {
  Loopback() {
    server = ModbusServer::ListenTcp("127.0.0.1", 0);
    client = ModbusClient::Open(server->backend() + ",timeout_ms=5000,retries=0");
  }
  std::unique_ptr<ModbusServer> server;
  std::unique_ptr<ModbusClient> client;
};

void BM_ReadHoldingRegisters10(benchmark::State& state) {
  Loopback loop;
  std::array<uint16_t, kCount> values{};
  for (auto _ : state) {
    std::error_code ec = loop.client->ReadHoldingRegisters(0, kCount, values.data());
    if (ec) {
      state.SkipWithError(loop.client->last_error_text().c_str());
      break;
    }
    benchmark::DoNotOptimize(values);
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_ReadHoldingRegisters10)->UseRealTime();

void BM_WriteRegisters10(benchmark::State& state) {
  Loopback loop;
  std::array<uint16_t, kCount> values{};
  uint16_t n = 0;
  for (auto _ : state) {
    values[0] = n++;
    std::error_code ec = loop.client->WriteRegisters(0, kCount, values.data());
    if (ec) {
      state.SkipWithError(loop.client->last_error_text().c_str());
      break;
    }
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_WriteRegisters10)->UseRealTime();

// The same write with a write hook installed, as a simulator has one.
void BM_WriteRegisters10WithHook(benchmark::State& state) {
  Loopback loop;
  uint64_t writes = 0;
  loop.server->SetWriteHook([&writes](const ModbusRequest& r, ModbusRegisterMap&) {
    writes += static_cast<uint64_t>(r.count);
  });
  std::array<uint16_t, kCount> values{};
  for (auto _ : state) {
    std::error_code ec = loop.client->WriteRegisters(0, kCount, values.data());
    if (ec) {
      state.SkipWithError(loop.client->last_error_text().c_str());
      break;
    }
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_WriteRegisters10WithHook)->UseRealTime();

}  // namespace
}  // namespace kinevis::hal
