// telehand-linkem: a user-space delay line between two network namespaces (the kernel here
// has no netem). It creates one TUN interface in each namespace, gives each a point-to-point
// address pointing at the other, and forwards every IP packet between them through the link
// model of common/link_emulation.h (one-way delay, jitter, Gilbert-Elliott loss, reordering),
// each direction with its own state. The interfaces vanish when it exits.
#include <arpa/inet.h>
#include <fcntl.h>
#include <net/if.h>
// After <net/if.h>: <linux/if_tun.h> needs struct ifreq but not <linux/if.h>.
#include <linux/if_tun.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <string>
#include <vector>

#include "telehand/app/cli.h"
#include "telehand/core/clock.h"
#include "telehand/core/error.h"
#include "telehand/netem/link_emulation.h"

namespace {

using namespace telehand;

[[noreturn]] void sysFail(const std::string& what) {
  throw Error(what + ": " + std::strerror(errno));
}

/// An open file descriptor, closed once.
class Fd {
 public:
  explicit Fd(int fd = -1) : fd_(fd) {}
  Fd(Fd&& o) noexcept : fd_(o.fd_) { o.fd_ = -1; }
  Fd& operator=(Fd&& o) noexcept {
    std::swap(fd_, o.fd_);
    return *this;
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd_ >= 0) close(fd_);
  }
  int get() const { return fd_; }

 private:
  int fd_;
};

void ifreqIoctl(int sock, unsigned long req, ifreq& ifr, const std::string& what) {
  if (ioctl(sock, req, &ifr) < 0) sysFail(what + " on " + ifr.ifr_name);
}

void setAddr(ifreq& ifr, sockaddr* field, const std::string& addr) {
  (void)ifr;
  sockaddr_in sin{};
  sin.sin_family = AF_INET;
  if (inet_pton(AF_INET, addr.c_str(), &sin.sin_addr) != 1) {
    throw ConfigError("'" + addr + "' is not an IPv4 address");
  }
  std::memcpy(field, &sin, sizeof sin);
}

void bringUp(int sock, const char* name) {
  ifreq ifr{};
  std::snprintf(ifr.ifr_name, IFNAMSIZ, "%s", name);
  ifreqIoctl(sock, SIOCGIFFLAGS, ifr, "read flags");
  ifr.ifr_flags = static_cast<short>(ifr.ifr_flags | IFF_UP | IFF_RUNNING);
  ifreqIoctl(sock, SIOCSIFFLAGS, ifr, "bring up");
}

/// Enter namespace `ns`, create the TUN `dev` there with `local` -> `peer`, come back.
Fd tunIn(const std::string& ns, const std::string& dev, const std::string& local,
         const std::string& peer, int home_ns) {
  const std::string path = "/var/run/netns/" + ns;
  Fd nsfd(open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (nsfd.get() < 0) sysFail("network namespace '" + ns + "' (" + path + ")");
  if (setns(nsfd.get(), CLONE_NEWNET) < 0) sysFail("enter network namespace '" + ns + "'");
  try {
    Fd tun(open("/dev/net/tun", O_RDWR | O_NONBLOCK | O_CLOEXEC));
    if (tun.get() < 0) sysFail("open /dev/net/tun");
    ifreq ifr{};
    ifr.ifr_flags = IFF_TUN | IFF_NO_PI;
    std::snprintf(ifr.ifr_name, IFNAMSIZ, "%s", dev.c_str());
    if (ioctl(tun.get(), TUNSETIFF, &ifr) < 0) sysFail("create TUN '" + dev + "' in '" + ns + "'");
    Fd sock(socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0));
    if (sock.get() < 0) sysFail("socket");
    setAddr(ifr, &ifr.ifr_addr, local);
    ifreqIoctl(sock.get(), SIOCSIFADDR, ifr, "set address " + local);
    setAddr(ifr, &ifr.ifr_dstaddr, peer);
    ifreqIoctl(sock.get(), SIOCSIFDSTADDR, ifr, "set peer " + peer);
    bringUp(sock.get(), dev.c_str());
    bringUp(sock.get(), "lo");
    if (setns(home_ns, CLONE_NEWNET) < 0) sysFail("return to the original network namespace");
    return tun;
  } catch (...) {
    setns(home_ns, CLONE_NEWNET);
    throw;
  }
}

struct Direction {
  const char* name;
  int from;
  int to;
  DelayLine<std::vector<uint8_t>> line;
  uint64_t forwarded = 0;
  uint64_t write_errors = 0;
};

void printStats(const Direction& d) {
  const auto& s = d.line.stats();
  const uint64_t delivered = s.sent - s.lost;
  std::printf(
      "%s: %llu packets, %llu lost (%.2f %%), %llu reordered, delay mean %.1f ms max %.1f ms, "
      "%llu forwarded, %llu write errors\n",
      d.name, static_cast<unsigned long long>(s.sent), static_cast<unsigned long long>(s.lost),
      s.sent ? 100.0 * static_cast<double>(s.lost) / static_cast<double>(s.sent) : 0.0,
      static_cast<unsigned long long>(s.reordered),
      delivered ? s.delay_sum_ms / static_cast<double>(delivered) : 0.0, s.delay_max_ms,
      static_cast<unsigned long long>(d.forwarded),
      static_cast<unsigned long long>(d.write_errors));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "telehand-linkem: user-space delay line (delay, jitter, Gilbert-Elliott loss, "
      "reordering) between two network namespaces, over a TUN interface in each"};
  std::string ns_a, ns_b, addr_a = "10.77.0.1", addr_b = "10.77.0.2", dev = "thlink0";
  std::string profile_path;
  uint64_t seed = 1;
  double seconds = 0.0;
  app.add_option("--ns-a", ns_a, "first network namespace (ip netns)")->required();
  app.add_option("--ns-b", ns_b, "second network namespace")->required();
  app.add_option("--addr-a", addr_a, "address in the first namespace")->capture_default_str();
  app.add_option("--addr-b", addr_b, "address in the second namespace")->capture_default_str();
  app.add_option("--dev", dev, "TUN interface name in both namespaces")->capture_default_str();
  app.add_option("--profile", profile_path, "link profile (deploy/links/*.toml)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--seed", seed, "random seed of both directions")->capture_default_str();
  app.add_option("--seconds", seconds, "stop after this long (0 = until SIGTERM/SIGINT)")
      ->check(CLI::Range(0.0, 1e6));
  TELEHAND_CLI_PARSE(app, argc, argv)

  try {
    if (dev.size() >= IFNAMSIZ)
      throw ConfigError("--dev '" + dev + "' is longer than " + std::to_string(IFNAMSIZ - 1) +
                        " characters");
    const LinkProfile profile = loadLinkProfile(profile_path);
    Fd home(open("/proc/self/ns/net", O_RDONLY | O_CLOEXEC));
    if (home.get() < 0) sysFail("open /proc/self/ns/net");
    Fd tun_a = tunIn(ns_a, dev, addr_a, addr_b, home.get());
    Fd tun_b = tunIn(ns_b, dev, addr_b, addr_a, home.get());

    installStopSignals(/*restart_syscalls=*/false);  // no call on the TUNs resumes after one

    Direction ab{"a->b", tun_a.get(), tun_b.get(),
                 DelayLine<std::vector<uint8_t>>(profile, seed * 2 + 1)};
    Direction ba{"b->a", tun_b.get(), tun_a.get(),
                 DelayLine<std::vector<uint8_t>>(profile, seed * 2 + 2)};
    std::printf(
        "linkem ready: %s %s (%s) <-> %s %s (%s), profile '%s': RTT %.0f ms, jitter ±%.0f ms, "
        "loss %.1f %% (bursts of %.0f), reordering %.1f %%\n",
        ns_a.c_str(), dev.c_str(), addr_a.c_str(), ns_b.c_str(), dev.c_str(), addr_b.c_str(),
        profile.name.c_str(), profile.rtt_ms, profile.jitter_ms, profile.loss_pct,
        profile.loss_burst, profile.reorder_pct);
    std::fflush(stdout);

    SteadyClock clock;
    const int64_t end =
        seconds > 0.0 ? clock.nowNs() + static_cast<int64_t>(seconds * 1e9) : INT64_MAX;
    std::vector<uint8_t> buf(65536);
    pollfd fds[2] = {{tun_a.get(), POLLIN, 0}, {tun_b.get(), POLLIN, 0}};
    Direction* dirs[2] = {&ab, &ba};
    while (!g_stop_requested.load() && clock.nowNs() < end) {
      const int64_t now = clock.nowNs();
      const int64_t next =
          std::min({ab.line.nextArrivalNs(), ba.line.nextArrivalNs(), now + 100 * kNsPerMs, end});
      const int64_t wait = std::max<int64_t>(next - now, 0);
      timespec ts{wait / kNsPerS, wait % kNsPerS};
      const int n = ppoll(fds, 2, &ts, nullptr);
      if (n < 0 && errno != EINTR) sysFail("ppoll");
      for (int i = 0; i < 2; ++i) {
        if (n <= 0 || !(fds[i].revents & POLLIN)) continue;
        while (true) {
          const ssize_t got = read(fds[i].fd, buf.data(), buf.size());
          if (got <= 0) break;
          dirs[i]->line.send(std::vector<uint8_t>(buf.begin(), buf.begin() + got), clock.nowNs());
        }
      }
      for (Direction* d : dirs) {
        d->line.deliver(clock.nowNs(), [&](const std::vector<uint8_t>& p) {
          if (write(d->to, p.data(), p.size()) == static_cast<ssize_t>(p.size())) {
            ++d->forwarded;
          } else {
            ++d->write_errors;
          }
        });
      }
    }
    printStats(ab);
    printStats(ba);
    return 0;
  } catch (const telehand::Error& e) {
    std::cerr << "telehand-linkem: " << e.what() << "\n";
    return 2;
  }
}
