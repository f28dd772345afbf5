#pragma once
/// Typed errors for set-up code. Messages name the file, field or value that was wrong.
#include <stdexcept>
#include <string>

namespace telehand {

/// Base of every error telehand throws.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A configuration or model file, or a command-line value, is malformed.
class ConfigError : public Error {
 public:
  using Error::Error;
};

/// A DDS call failed; the message carries Cyclone's return code text.
class DdsError : public Error {
 public:
  using Error::Error;
};

/// The session store could not read or write a record.
class StoreError : public Error {
 public:
  using Error::Error;
};

/// A device could not be opened or misbehaved during set-up.
class DeviceError : public Error {
 public:
  using Error::Error;
};

}  // namespace telehand
