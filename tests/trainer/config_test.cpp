#include "trainer/config.h"

#include <gtest/gtest.h>

#include "common/error.h"

namespace dofarm::trainer {
namespace {

TEST(TrainConfig, DefaultsAreThesisValues) {
  TrainConfig c = load_train_config("");
  EXPECT_TRUE(c.model.dof);
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{36, 48, 64, 85, 113}));
  c.model.dof = false;
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{32, 43, 57, 76, 101}));
  EXPECT_EQ(c.data.sequence, 7);
  EXPECT_EQ(c.data.crop, 64);
  EXPECT_FLOAT_EQ(c.data.stop_probability, 0.25f);
  EXPECT_FLOAT_EQ(c.loss.l1, 0.8f);
  EXPECT_FLOAT_EQ(c.loss.log, 0.2f);
  EXPECT_EQ(c.train.batch, 4);
  EXPECT_FLOAT_EQ(c.train.beta2, 0.99f);
}

TEST(TrainConfig, ReadsFileAndOverrides) {
  TrainConfig c = parse_train_config(
      "[train]\nepochs = 5\nlr = 2e-4\n[model]\nchannels = [8, 8, 8, 8, 8]\n", "t.toml",
      {"train.epochs=2", "train.device=cpu", "data.albedo=\"version\""});
  EXPECT_EQ(c.train.epochs, 2);
  EXPECT_FLOAT_EQ(c.train.lr, 2e-4f);
  EXPECT_EQ(c.train.device, "cpu");
  EXPECT_EQ(c.data.albedo, AlbedoSource::kVersion);
  EXPECT_EQ(c.model.effective_channels(), (std::vector<int>{8, 8, 8, 8, 8}));
}

TEST(TrainConfig, UnknownKeyIsALocatedError) {
  try {
    parse_train_config("[train]\nepochs = 5\n  epoch = 3\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_STREQ(e.what(), "t.toml:3:11: \"train.epoch\": unknown key");
  }
}

TEST(TrainConfig, BadValueIsALocatedError) {
  try {
    parse_train_config("[train]\nepochs = -1\n", "t.toml");
    FAIL() << "no error";
  } catch (const SpecError& e) {
    EXPECT_EQ(e.loc().line, 2);
    EXPECT_EQ(e.loc().column, 10);
    EXPECT_EQ(e.key(), "epochs");
    EXPECT_NE(std::string(e.what()).find("got -1"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.epochs=zero"}), SpecError);
  EXPECT_THROW(parse_train_config("", "t.toml", {"train.nothing=1"}), SpecError);
  EXPECT_THROW(parse_train_config("", "t.toml", {"data.crop=48"}), SpecError);
  EXPECT_THROW(parse_train_config("[train\n", "t.toml"), SpecError);
}

TEST(TrainConfig, RoundTripsThroughToml) {
  TrainConfig c = parse_train_config(
      "", "t.toml",
      {"train.epochs=7", "model.recurrent=true", "loss.temporal=0.25", "train.seed=42"});
  TrainConfig back = parse_train_config(to_toml(c), "config.toml");
  EXPECT_EQ(to_toml(back), to_toml(c));
  EXPECT_EQ(back.train.epochs, 7);
  EXPECT_TRUE(back.model.recurrent);
  EXPECT_EQ(back.train.seed, 42u);
}

TEST(TrainConfig, IncompatibleReasonNamesModelKeysOnly) {
  TrainConfig a = load_train_config("");
  TrainConfig b = a;
  b.train.epochs = 500;  // schedule: fine to change on resume
  EXPECT_EQ(incompatible_reason(a, b), "");
  b.model.recurrent = true;
  std::string why = incompatible_reason(a, b);
  EXPECT_NE(why.find("model.recurrent"), std::string::npos) << why;
}

}  // namespace
}  // namespace dofarm::trainer
