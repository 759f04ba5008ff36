// Defect 9 of issue 10: `dofarm keygen` made the secret key world-readable
// for a moment (0666, then chmod), followed a planted symlink and silently
// overwrote an existing key pair. Each test runs the real executable.
#include <sys/stat.h>

#include <cstdlib>

#include "tests/farm/farm_fixtures.h"

namespace dofarm::farm_testing {
namespace {

unsigned mode_of(const fs::path& p) {
  struct stat st {};
  if (::lstat(p.c_str(), &st) != 0) return 0xFFFF;
  return st.st_mode & 07777;
}

std::string first_line_of(const fs::path& p) {
  std::string text = read_text(p);
  return text.substr(0, text.find('\n'));
}

// The command through /bin/sh, to set the umask and limits first; returns
// the shell's exit status (128 + N when the command was killed by signal N).
int shell(const std::string& script) {
  // The outer shell's own report of a killed command goes nowhere.
  const int st = std::system(("/bin/sh -c '" + script + "' 2>/dev/null").c_str());
  return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

TEST(FarmKeygen, KeysHaveTheirModesUnderAnyUmask) {
  TempDir tmp;
  const fs::path keys = tmp / "keys";
  ASSERT_EQ(shell("umask 0 && exec " + dofarm_exe().string() + " keygen --out " + keys.string() +
                  " >/dev/null"),
            0);
  EXPECT_EQ(mode_of(keys / "coordinator.key"), 0600u);
  EXPECT_EQ(mode_of(keys / "coordinator.pub"), 0644u);
  EXPECT_EQ(mode_of(keys), 0700u) << "a folder keygen creates is private";
  EXPECT_EQ(curve_public_of(first_line_of(keys / "coordinator.key")),
            first_line_of(keys / "coordinator.pub"));
}

// A keygen killed in the middle of writing the secret (the file size limit
// 0 kills it with SIGXFSZ at its first write) leaves what it had created at
// that moment: none of it may be readable by others. The old keygen left a
// 0666 coordinator.key here.
TEST(FarmKeygen, SecretIsPrivateFromTheMomentItIsCreated) {
  TempDir tmp;
  const fs::path keys = tmp / "keys";
  fs::create_directories(keys);
  fs::permissions(keys, fs::perms::owner_all);
  const int rc = shell("umask 0 && ulimit -f 0 && exec " + dofarm_exe().string() +
                       " keygen --out " + keys.string() + " >/dev/null 2>&1");
  EXPECT_NE(rc, 0) << "keygen wrote a key under a file size limit of 0";
  int files = 0;
  for (const auto& entry : fs::directory_iterator(keys)) {
    ++files;
    EXPECT_EQ(mode_of(entry.path()) & 077u, 0u)
        << entry.path() << " has mode " << std::oct << mode_of(entry.path());
  }
  EXPECT_GE(files, 1) << "keygen created no file before its first write";
  EXPECT_FALSE(fs::exists(keys / "coordinator.key")) << "a half-written key was published";
}

TEST(FarmKeygen, PlantedSymlinkIsNeverFollowed) {
  TempDir tmp;
  const fs::path keys = tmp / "keys", victim = tmp / "victim";
  fs::create_directories(keys);
  write_text(victim, "precious\n");
  fs::permissions(victim, fs::perms(0644));
  fs::create_symlink(victim, keys / "coordinator.key");
  CliResult r = run_cli(tmp.path(), "keygen", {"keygen", "--out", keys.string()});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find((keys / "coordinator.key").string()), std::string::npos) << r.err;
  EXPECT_EQ(read_text(victim), "precious\n");
  EXPECT_EQ(mode_of(victim), 0644u);
  EXPECT_TRUE(fs::is_symlink(keys / "coordinator.key"));
  EXPECT_FALSE(fs::exists(keys / "coordinator.pub")) << "half a pair was written";

  // A dangling symlink would have created its target.
  const fs::path keys2 = tmp / "keys2", target = tmp / "planted-target";
  fs::create_directories(keys2);
  fs::create_symlink(target, keys2 / "coordinator.pub");
  r = run_cli(tmp.path(), "keygen2", {"keygen", "--out", keys2.string()});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_FALSE(fs::exists(target));
  EXPECT_FALSE(fs::exists(keys2 / "coordinator.key")) << "half a pair was written";

  // The key folder itself as a symlink: refused, nothing written there.
  const fs::path real = tmp / "elsewhere", link = tmp / "keys-link";
  fs::create_directories(real);
  fs::create_directory_symlink(real, link);
  r = run_cli(tmp.path(), "keygen3", {"keygen", "--out", link.string()});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("symlink"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::is_empty(real));
}

TEST(FarmKeygen, ExistingPairIsNotOverwrittenWithoutForce) {
  TempDir tmp;
  const fs::path keys = tmp / "keys";
  ASSERT_EQ(run_cli(tmp.path(), "first", {"keygen", "--out", keys.string()}).status, 0);
  const std::string secret = read_text(keys / "coordinator.key");
  const std::string pub = read_text(keys / "coordinator.pub");
  CliResult r = run_cli(tmp.path(), "second", {"keygen", "--out", keys.string()});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find((keys / "coordinator.key").string()), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--force"), std::string::npos) << r.err;
  EXPECT_EQ(read_text(keys / "coordinator.key"), secret);
  EXPECT_EQ(read_text(keys / "coordinator.pub"), pub);

  // A lone public key is refused too, and no secret is left next to it.
  const fs::path lone = tmp / "lone";
  fs::create_directories(lone);
  write_text(lone / "w1.pub", "old\n");
  r = run_cli(tmp.path(), "lone", {"keygen", "--client", "w1", "--out", lone.string()});
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find((lone / "w1.pub").string()), std::string::npos) << r.err;
  EXPECT_EQ(read_text(lone / "w1.pub"), "old\n");
  EXPECT_FALSE(fs::exists(lone / "w1.key"));
  for (const auto& entry : fs::directory_iterator(lone))
    EXPECT_EQ(entry.path().filename(), "w1.pub") << "left behind: " << entry.path();
}

TEST(FarmKeygen, ForceReplacesEachFileAtomically) {
  TempDir tmp;
  const fs::path keys = tmp / "keys";
  ASSERT_EQ(run_cli(tmp.path(), "first", {"keygen", "--out", keys.string()}).status, 0);
  const std::string old_secret = read_text(keys / "coordinator.key");
  // A second name for the old file: a rename leaves it as it was, a rewrite
  // in place would change it.
  fs::create_hard_link(keys / "coordinator.key", tmp / "old.key");
  CliResult r = run_cli(tmp.path(), "force", {"keygen", "--out", keys.string(), "--force"});
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string secret = first_line_of(keys / "coordinator.key");
  EXPECT_NE(secret + "\n", old_secret);
  EXPECT_EQ(read_text(tmp / "old.key"), old_secret) << "the old key was rewritten in place";
  EXPECT_EQ(mode_of(keys / "coordinator.key"), 0600u);
  EXPECT_EQ(curve_public_of(secret), first_line_of(keys / "coordinator.pub"));

  // --force replaces a planted symlink itself, never its target.
  const fs::path victim = tmp / "victim";
  write_text(victim, "precious\n");
  fs::remove(keys / "coordinator.pub");
  fs::create_symlink(victim, keys / "coordinator.pub");
  r = run_cli(tmp.path(), "force2", {"keygen", "--out", keys.string(), "--force"});
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(read_text(victim), "precious\n");
  EXPECT_FALSE(fs::is_symlink(keys / "coordinator.pub"));
  EXPECT_EQ(curve_public_of(first_line_of(keys / "coordinator.key")),
            first_line_of(keys / "coordinator.pub"));
  for (const auto& entry : fs::directory_iterator(keys))
    EXPECT_NE(entry.path().filename().string()[0], '.') << "left behind: " << entry.path();
}

TEST(FarmKeygen, ClientKeyPairsAreNamedAndChecked) {
  TempDir tmp;
  const fs::path keys = tmp / "keys";
  CliResult r =
      run_cli(tmp.path(), "client", {"keygen", "--client", "render-01", "--out", keys.string()});
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string pub = first_line_of(keys / "render-01.pub");
  EXPECT_EQ(curve_public_of(first_line_of(keys / "render-01.key")), pub);
  EXPECT_EQ(mode_of(keys / "render-01.key"), 0600u);
  EXPECT_NE(r.out.find(pub + " ROLE render-01"), std::string::npos) << r.out;
  for (const std::string bad : {"../up", "coordinator", ".hidden", "a b"}) {
    CliResult b = run_cli(tmp.path(), "bad", {"keygen", "--client", bad, "--out", keys.string()});
    EXPECT_EQ(b.status, 2) << bad << ": " << b.err;
  }
  EXPECT_FALSE(fs::exists(tmp / "up.key"));
}

}  // namespace
}  // namespace dofarm::farm_testing
