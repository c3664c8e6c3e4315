/* The CLI's option and number parsers and its command scaffold
 * (cli_run), in-process, value by value. */
#include <float.h>
#include <stdio.h>
#include <string.h>

#include "cli.h"
#include "gs_test.h"

/* cli.h declares these; the test links args.c alone. */
const cli_command cli_render_command = {"render", "", "usage: test\n", .run = NULL};
const cli_command cli_scene_command = {"scene", "", "usage: test\n", .run = NULL};
int cli_demo_head(unsigned long seed, struct gs_ply_scene *out)
{
    (void)seed, (void)out;
    return -1;
}

static void test_floats(void)
{
    static const char *const bad4[] = {
        "300,300,128",       "300,300,128,128,1", "300,300,1x,128", "nan,300,128,128",
        "inf,300,128,128",   "300,,128,128",      "",               "1e39,300,128,128",
        " 300,300,128,128",  "300 ,300,128,128",  "300,300,128,128,", ",300,300,128,128",
        "300;300;128;128",   "-inf,1,2,3",        "1,2,3,4 ",       "0x,1,2,3",
    };
    float v[4];
    for (size_t i = 0; i < sizeof bad4 / sizeof bad4[0]; i++)
        CHECK_MSG(cli_parse_floats(bad4[i], v, 4) == -1, "'%s' accepted", bad4[i]);
    CHECK_EQ_INT(cli_parse_floats("300,-2.5,1e-3,+7", v, 4), 0);
    CHECK(v[0] == 300.0f && v[1] == -2.5f && v[2] == 1e-3f && v[3] == 7.0f);
    CHECK_EQ_INT(cli_parse_floats("3.4e38,0,0,0", v, 4), 0);
    float m[12];
    CHECK_EQ_INT(cli_parse_floats("1,0,0,0,0,1,0,0,0,0,1,4", m, 12), 0);
    CHECK(m[0] == 1 && m[5] == 1 && m[10] == 1 && m[11] == 4);
    CHECK_EQ_INT(cli_parse_floats("1,0,0,0,0,1,0,0,0,0,1", m, 12), -1);
}

static void test_size_and_long(void)
{
    static const char *const bad[] = {"0x256", "256x0", "9000x10", "10x9000", "abc", "256",
                                      "256x", "x256", "-5x5", "256x256x3", "1e3x5", "+5x5",
                                      "99999999999999999999x5", " 5x5", "5x 5", ""};
    int w = 0, h = 0;
    long l = 0;
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        CHECK_MSG(cli_parse_size(bad[i], 8192, &w, &h) == -1, "'%s' accepted", bad[i]);
    CHECK(cli_parse_size("256x128", 8192, &w, &h) == 0 && w == 256 && h == 128);
    CHECK(cli_parse_size("8192X1", 8192, &w, &h) == 0 && w == 8192 && h == 1);
    CHECK_EQ_INT(cli_parse_long("0", 1, 256, &l), -1);
    CHECK_EQ_INT(cli_parse_long("257", 1, 256, &l), -1);
    CHECK_EQ_INT(cli_parse_long("1.5", 1, 256, &l), -1);
    CHECK_EQ_INT(cli_parse_long("two", 1, 256, &l), -1);
    CHECK_EQ_INT(cli_parse_long("", 1, 256, &l), -1);
    CHECK_EQ_INT(cli_parse_long("99999999999999999999999", 0, 4294967295L, &l), -1);
    CHECK(cli_parse_long("256", 1, 256, &l) == 0 && l == 256);
    CHECK(cli_parse_long("4294967295", 0, 4294967295L, &l) == 0 && l == 4294967295L);
}

/* Rates are read as doubles: "0.004" is the double 0.004 that a config key
 * or a protocol field holds, not a float widened. */
static void test_rate(void)
{
    double r = -1;
    CHECK(cli_parse_rate("0.004", 1.0, &r) == 0 && r == 0.004);
    CHECK(cli_parse_rate("1", 1.0, &r) == 0 && r == 1.0);
    CHECK(cli_parse_rate("2.5e-4", 1.0, &r) == 0 && r == 2.5e-4);
    const char *bad[] = {"0", "-0.001", "1.0000001", "nan", "inf", "", "0.01x", "x", "1e999", "1e-999"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        r = 0.5;
        CHECK_MSG(cli_parse_rate(bad[i], 1.0, &r) == -1 && r == 0.5, "'%s'", bad[i]);
    }
}

static int parse(int n, const char **args, cli_opt *o, int no)
{
    char *argv[16];
    for (int i = 0; i < n; i++)
        argv[i] = (char *)args[i];
    for (int i = 0; i < no; i++)
        o[i].value = NULL;
    return cli_parse(&cli_render_command, n, argv, o, no);
}

static void test_options(void)
{
    cli_opt o[3] = {{"--size", 1, NULL}, {"--flag", 0, NULL}, {"--out", 1, NULL}};
    const char *ok[] = {"render", "--size", "5x5", "--flag", "--out=a.png"};
    CHECK_EQ_INT(parse(5, ok, o, 3), CLI_PARSED);
    CHECK(strcmp(o[0].value, "5x5") == 0 && o[1].value && strcmp(o[2].value, "a.png") == 0);
    const char *help[] = {"render", "--size", "5x5", "-h"};
    CHECK_EQ_INT(parse(4, help, o, 3), CLI_HELP);
    const char *none[] = {"render"};
    CHECK(parse(1, none, o, 3) == CLI_PARSED && !o[0].value && !o[1].value);
    const char *bad[][3] = {{"render", "--size", NULL},      {"render", "--bogus", "x"},
                            {"render", "--flag=1", "x"},     {"render", "stray", "x"},
                            {"render", "--size=1", "--size"}, {"render", "-s", "x"}};
    const int nbad[] = {2, 2, 2, 2, 3, 2};
    for (size_t i = 0; i < sizeof nbad / sizeof nbad[0]; i++)
        CHECK_MSG(parse(nbad[i], bad[i], o, 3) == CLI_USAGE, "case %zu accepted", i);
}

/* Target lists: strict numbers, then the target table (inclusive). Each
 * refusal prints its message and the usage to stderr. */
static void test_angles(void)
{
    const cli_command *cmd = &cli_render_command;
    double v[8][2];
    int n = -1;
    static const char *const bad_list[] = {
        "",          ";",          "0,0;",        ";0,0",       "0,0;;1,1",  "0",
        "0,",        ",0",         "0,0,0",       "0,0x",       " 0,0",      "0 ,0",
        "0,0 ",      "nan,0",      "0,inf",       "-inf,0",     "1e400,0",   "0x10,0",
        "200,0",     "1e30,1e30",  "50.000000001,0", "0,-60.000000001", "0,0;0,0;0,0;0,0;0,0;0,61",
        "1,1;2,2;3,3;4,4;5,5;6,6;7,7;8,8;9,9", /* more than 8 */
    };
    for (size_t i = 0; i < sizeof bad_list / sizeof bad_list[0]; i++)
        CHECK_MSG(cli_parse_angles(cmd, "--gaze-deg", bad_list[i], 1, 0, v, 8, &n) == CLI_USAGE,
                  "gaze list '%s' accepted", bad_list[i]);
    CHECK(cli_parse_angles(cmd, "--gaze-deg", NULL, 1, 0, v, 8, &n) == CLI_USAGE);
    /* The limits themselves, and one list of several. */
    CHECK_EQ_INT(cli_parse_angles(cmd, "--gaze-deg", "50,60;-50,-60;+0.5,-1e-3;0,0", 1, 0, v, 8, &n),
                 CLI_OK);
    CHECK(n == 4 && v[0][0] == 50 && v[0][1] == 60 && v[1][0] == -50 && v[1][1] == -60 &&
          v[2][0] == 0.5 && v[2][1] == -1e-3);
    /* One pair: a list is junk; a head's range is +-70. */
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "70,-70", 0, 1, v, 1, &n), CLI_OK);
    CHECK(n == 1 && v[0][0] == 70 && v[0][1] == -70);
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "0,0;0,0", 0, 1, v, 1, &n), CLI_USAGE);
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "70.000000001,0", 0, 1, v, 1, &n), CLI_USAGE);
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "1e30,1e30", 0, 1, v, 1, &n), CLI_USAGE);
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "", 0, 1, v, 1, &n), CLI_USAGE);
    /* 70 is a head's limit, not a gaze's. */
    CHECK_EQ_INT(cli_parse_angles(cmd, "--gaze-deg", "0,70", 0, 0, v, 1, &n), CLI_USAGE);
    CHECK_EQ_INT(cli_parse_angles(cmd, "--head-deg", "0,70;-70,0", 1, 1, v, 8, &n), CLI_OK);
    CHECK(n == 2);
}

/* Per-image labels ("P,Y;-;P,Y", one item per image) and path lists. */
static void test_image_lists(void)
{
    const cli_command *cmd = &cli_render_command;
    double v[4][2];
    int known[4];
    CHECK_EQ_INT(cli_parse_image_labels(cmd, "--gaze-deg", "5,0;-;-3.5,2", 0, 3, v, known), CLI_OK);
    CHECK(known[0] && !known[1] && known[2] && v[0][0] == 5 && v[2][0] == -3.5 && v[2][1] == 2);
    CHECK_EQ_INT(cli_parse_image_labels(cmd, "--gaze-deg", "5,0", 0, 1, v, known), CLI_OK);
    CHECK(known[0] && v[0][0] == 5);
    static const char *const bad[] = {"5,0;1,1", "5,0;-;1,1;2,2", "", "5,0;;1,1", "5,0;x;1,1",
                                      "5,0;-;0,99", "5;-;1,1"};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++)
        CHECK_MSG(cli_parse_image_labels(cmd, "--gaze-deg", bad[i], 0, 3, v, known) == CLI_USAGE,
                  "'%s' accepted", bad[i]);
    CHECK_EQ_INT(cli_parse_image_labels(cmd, "--head-deg", "-;70,-70", 1, 2, v, known), CLI_OK);
    CHECK_EQ_INT(cli_parse_image_labels(cmd, "--head-deg", "-;71,0", 1, 2, v, known), CLI_USAGE);
    const char *p[4];
    char *buf = NULL;
    int n = 0;
    CHECK_EQ_INT(cli_split_paths(cmd, "--image", "a.png,b c.png,d.png", 4, &buf, p, &n), CLI_OK);
    CHECK(n == 3 && !strcmp(p[0], "a.png") && !strcmp(p[1], "b c.png") && !strcmp(p[2], "d.png"));
    free(buf);
    CHECK_EQ_INT(cli_split_paths(cmd, "--image", "a.png", 4, &buf, p, &n), CLI_OK);
    CHECK(n == 1 && !strcmp(p[0], "a.png"));
    free(buf);
    static const char *const badp[] = {"", "a,,b", "a,", ",a", "a,b,c,d,e"};
    for (size_t i = 0; i < sizeof badp / sizeof badp[0]; i++) {
        CHECK_MSG(cli_split_paths(cmd, "--image", badp[i], 4, &buf, p, &n) == CLI_USAGE,
                  "'%s' accepted", badp[i]);
        CHECK(buf == NULL);
    }
}

/* cli_run: the table's copy parsed and handed over, help and bad usage
 * answered without running the command, the table left as it was; a raw
 * command gets argv as given; the command line as run. */
static int ran, ran_raw;
static const cli_opt *ran_opts;
static char ran_size[16], ran_line[64];

static int run_test(const cli_command *cmd, cli_opt *o)
{
    ran++;
    ran_opts = o;
    snprintf(ran_size, sizeof ran_size, "%s", o[0].value ? o[0].value : "-");
    cli_command_line(ran_line, sizeof ran_line);
    return o[1].value ? CLI_OUTLIERS : (cmd->nopts == 2 ? CLI_OK : CLI_FAIL);
}

static int run_raw(int argc, char **argv)
{
    ran_raw++;
    return argc == 3 && !strcmp(argv[1], "verb") && !strcmp(argv[2], "--x") ? CLI_OK : CLI_FAIL;
}

static const cli_opt test_opts[] = {{"--size", 1, NULL}, {"--flag", 0, NULL}};
static const cli_command test_cmd = {"test", "", "usage: gazesplat test\n", .opts = test_opts,
                                     .nopts = CLI_NOPTS(test_opts), .run_opts = run_test};
static const cli_command raw_cmd = {"raw", "", "usage: gazesplat raw\n", .run = run_raw};

static void test_run(void)
{
    char *ok[] = {"test", "--size", "5x5"};
    CHECK_EQ_INT(cli_run(&test_cmd, 3, ok), CLI_OK);
    CHECK(ran == 1 && ran_opts != test_opts && !strcmp(ran_size, "5x5"));
    CHECK_MSG(!strcmp(ran_line, "gazesplat test --size 5x5"), "command line '%s'", ran_line);
    CHECK(!test_opts[0].value && !test_opts[1].value);
    char *flag[] = {"test", "--flag"};
    CHECK_EQ_INT(cli_run(&test_cmd, 2, flag), CLI_OUTLIERS); /* its own status */
    CHECK(ran == 2 && !strcmp(ran_size, "-"));
    char *help[] = {"test", "--size", "1", "--help"};
    CHECK_EQ_INT(cli_run(&test_cmd, 4, help), CLI_OK);
    char *bad[] = {"test", "--bogus"};
    CHECK_EQ_INT(cli_run(&test_cmd, 2, bad), CLI_USAGE);
    char *twice[] = {"test", "--flag", "--flag"};
    CHECK_EQ_INT(cli_run(&test_cmd, 3, twice), CLI_USAGE);
    CHECK_MSG(ran == 2, "help and bad usage ran the command (%d runs)", ran);
    char *raw[] = {"raw", "verb", "--x"};
    CHECK_EQ_INT(cli_run(&raw_cmd, 3, raw), CLI_OK);
    CHECK(ran_raw == 1);
    cli_command_line(ran_line, 10);
    CHECK_MSG(!strcmp(ran_line, "gazesplat"), "cut at 10 bytes: '%s'", ran_line);
}

int main(void)
{
    test_floats();
    test_angles();
    test_image_lists();
    test_size_and_long();
    test_rate();
    test_options();
    test_run();
    GS_TEST_END();
}
