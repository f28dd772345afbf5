#pragma once
/// The record of one tick, written once for the haptic loop and the capture rig: what the
/// device read, with the thimble forces of paper eqs. 1-2, and what the joint proxy rendered.
#include "telehand/core/joint_model.h"
#include "telehand/core/sample.h"
#include "telehand/devices/device.h"

namespace telehand::devices {

/// Fill `s`'s fingers (pose, FSRs, thimble forces, `command_n`), its MCP angles and torques
/// and the FSR fault bits of its flags from one device reading. Returns the applied force
/// the thimbles measured, summed over both fingers (device frame). Real-time safe.
Vec3 recordTick(const DeviceSample& d, const PerFinger<Vec3>& command_n,
                const ProxyOutput& rendered, Sample& s) noexcept;

}  // namespace telehand::devices
