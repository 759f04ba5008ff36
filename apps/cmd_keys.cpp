// dofarm keygen: CURVE key pairs for the coordinator and for its clients
// (docs/farm.md, "Authentication (CURVE)").
//
// A secret key is never readable by anyone but its owner, not even for a
// moment, and nothing is ever written through a symlink or over an existing
// key without --force:
//   - each file is written under a fresh temporary name in the key folder,
//     created with open(O_CREAT | O_EXCL | O_NOFOLLOW, 0600) (0644 for the
//     public key), written and fsynced;
//   - then published: without --force with link(), which never replaces
//     anything (an existing file or symlink is an error naming it); with
//     --force with rename(), which replaces the name itself (a symlink there
//     is replaced, its target untouched) in one atomic step;
//   - the folder is opened with O_NOFOLLOW: a symlink as its last component
//     is refused (folders above it are resolved as usual); a folder that
//     does not exist is created with mode 0700.
// Files are published secret first; a failure before the public key is
// published removes the secret this run published, so no half pair is left.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <random>
#include <string>

#include "apps/commands.h"
#include "common/error.h"
#include "common/transport.h"

namespace dofarm {
namespace {

namespace fs = std::filesystem;

std::string errno_text() { return std::strerror(errno); }

// An open file descriptor, closed on scope exit.
class Fd {
 public:
  explicit Fd(int fd = -1) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

// Opens (creating with 0700 if absent) the key folder without following a
// symlink as its last component.
int open_key_folder(const fs::path& dir) {
  const fs::path folder = dir.empty() ? fs::path(".") : dir;
  if (::mkdir(folder.c_str(), 0700) != 0 && errno != EEXIST) {
    // Missing parents are created as usual (their mode is not secret).
    std::error_code ec;
    if (folder.has_parent_path()) fs::create_directories(folder.parent_path(), ec);
    if (ec || (::mkdir(folder.c_str(), 0700) != 0 && errno != EEXIST))
      throw RuntimeError("cannot create the key folder " + folder.string() + ": " +
                         (ec ? ec.message() : errno_text()));
  }
  int fd = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) {
    struct stat st {};
    if (::lstat(folder.c_str(), &st) == 0 && S_ISLNK(st.st_mode))
      throw SpecError(FileLoc{"--out " + dir.string()}, "",
                      "the key folder is a symlink; keys are never written through one (name "
                      "the folder it points to)");
    if (errno == ENOTDIR) throw SpecError(FileLoc{"--out " + dir.string()}, "", "not a folder");
    throw RuntimeError("cannot open the key folder " + folder.string() + ": " + errno_text());
  }
  return fd;
}

// Writes `text` to a fresh temporary file in the folder with `mode` from
// its creation on; returns its name.
std::string write_temporary(int dirfd, const fs::path& dir, const std::string& name,
                            const std::string& text, mode_t mode) {
  std::random_device rd;
  for (int tries = 0; tries < 16; ++tries) {
    const std::string tmp =
        "." + name + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(rd() % 1000000);
    Fd fd(::openat(dirfd, tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, mode));
    if (fd.get() < 0) {
      if (errno == EEXIST) continue;
      throw RuntimeError("cannot create " + (dir / tmp).string() + ": " + errno_text());
    }
    // The umask may only have removed bits; make the mode exact.
    bool ok = ::fchmod(fd.get(), mode) == 0;
    size_t written = 0;
    while (ok && written < text.size()) {
      ssize_t n = ::write(fd.get(), text.data() + written, text.size() - written);
      if (n < 0 && errno == EINTR) continue;
      ok = n > 0;
      if (ok) written += size_t(n);
    }
    ok = ok && ::fsync(fd.get()) == 0;
    if (!ok) {
      const std::string why = errno_text();
      ::unlinkat(dirfd, tmp.c_str(), 0);
      throw RuntimeError("cannot write " + (dir / tmp).string() + ": " + why);
    }
    return tmp;
  }
  throw RuntimeError("cannot find a free temporary name in " + dir.string());
}

struct KeyPairFiles {
  std::string key, pub;  // file names in the folder: NAME.key, NAME.pub
};

// Publishes the written temporary files under their names (see the top).
void publish(int dirfd, const fs::path& dir, const KeyPairFiles& names, const KeyPairFiles& tmp,
             bool force) {
  auto cleanup = [&] {
    ::unlinkat(dirfd, tmp.key.c_str(), 0);
    ::unlinkat(dirfd, tmp.pub.c_str(), 0);
  };
  auto refuse = [&](const std::string& name) {
    cleanup();
    struct stat st {};
    const bool link =
        ::fstatat(dirfd, name.c_str(), &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISLNK(st.st_mode);
    throw SpecError(FileLoc{(dir / name).string()}, "",
                    std::string(link ? "exists as a symlink, which is never followed" : "exists") +
                        "; a key pair is never overwritten (pass --force to replace it)");
  };
  if (!force) {
    // Neither may exist: a lone .pub left behind is refused as well, so the
    // pair published here is always a pair.
    struct stat st {};
    for (const std::string& name : {names.key, names.pub})
      if (::fstatat(dirfd, name.c_str(), &st, AT_SYMLINK_NOFOLLOW) == 0) refuse(name);
    // link() fails with EEXIST if the name appeared since: nothing replaced.
    if (::linkat(dirfd, tmp.key.c_str(), dirfd, names.key.c_str(), 0) != 0) {
      if (errno == EEXIST) refuse(names.key);
      const std::string why = errno_text();
      cleanup();
      throw RuntimeError("cannot publish " + (dir / names.key).string() + ": " + why);
    }
    if (::linkat(dirfd, tmp.pub.c_str(), dirfd, names.pub.c_str(), 0) != 0) {
      const int err = errno;
      ::unlinkat(dirfd, names.key.c_str(), 0);  // ours: published a moment ago
      if (err == EEXIST) refuse(names.pub);
      cleanup();
      throw RuntimeError("cannot publish " + (dir / names.pub).string() + ": " +
                         std::strerror(err));
    }
    cleanup();
  } else {
    for (const auto& [from, to] : {std::pair{tmp.key, names.key}, {tmp.pub, names.pub}}) {
      if (::renameat(dirfd, from.c_str(), dirfd, to.c_str()) != 0) {
        const std::string why = errno_text();
        cleanup();
        throw RuntimeError("cannot replace " + (dir / to).string() + ": " + why);
      }
    }
  }
  ::fsync(dirfd);  // the names, durably
}

// A client name becomes a file name: letters, digits, '.', '_', '-'; not
// starting with '.'; not "coordinator" (the coordinator's own pair).
void check_client_name(const std::string& name) {
  const FileLoc loc{"--client " + name};
  if (name.empty() || name.size() > 64)
    throw SpecError(loc, "", "a client name has 1 to 64 characters");
  for (char c : name)
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '.' || c == '_' || c == '-'))
      throw SpecError(loc, "",
                      "a client name may hold letters, digits, '.', '_' and '-' only (it names "
                      "the key files)");
  if (name[0] == '.' || name[0] == '-')
    throw SpecError(loc, "", "a client name may not start with '.' or '-'");
  if (name == "coordinator")
    throw SpecError(loc, "", "\"coordinator\" names the coordinator's own key pair");
}

}  // namespace

Command add_keygen(CLI::App& app) {
  struct Args {
    std::string dir, client;
    bool force = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "keygen",
      "Make a CURVE key pair: coordinator.key (secret, mode 0600) and coordinator.pub, or with "
      "--client NAME a client's NAME.key and NAME.pub");
  cmd->add_option("--out", a->dir, "folder for the key files (created with mode 0700)")
      ->type_name("DIR")
      ->required();
  cmd->add_option("--client", a->client,
                  "a client's key pair (a worker's or an operator's) instead of the "
                  "coordinator's; list its public key in the coordinator's --curve-clients file")
      ->type_name("NAME");
  cmd->add_flag("--force", a->force, "replace an existing key pair (each file atomically)");
  return {cmd, [a]() {
            if (!a->client.empty()) check_client_name(a->client);
            const std::string base = a->client.empty() ? "coordinator" : a->client;
            const KeyPairFiles names{base + ".key", base + ".pub"};
            const auto [pub, sec] = curve_keypair();
            const fs::path dir(a->dir);
            Fd dirfd(open_key_folder(dir));
            KeyPairFiles tmp;
            tmp.key = write_temporary(dirfd.get(), dir, names.key, sec + "\n", 0600);
            try {
              tmp.pub = write_temporary(dirfd.get(), dir, names.pub, pub + "\n", 0644);
            } catch (...) {
              ::unlinkat(dirfd.get(), tmp.key.c_str(), 0);
              throw;
            }
            publish(dirfd.get(), dir, names, tmp, a->force);
            std::cout << "wrote " << (dir / names.key).string() << " and "
                      << (dir / names.pub).string() << std::endl;
            if (!a->client.empty())
              std::cout << "allow it with this line in the coordinator's --curve-clients file "
                           "(ROLE: worker or operator):\n"
                        << pub << " ROLE " << a->client << std::endl;
            return kExitOk;
          }};
}

}  // namespace dofarm
