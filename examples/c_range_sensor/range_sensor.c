/*
 * A range sensor in C on zenoh-pico, written from docs/protocol.md alone: the C twin of
 * examples/plain_range_sensor.py (build and run: README.md beside this file).
 *
 *     ./range_sensor -e tcp/127.0.0.1:7447 -r mini -n ext -d 250 -z 20 -c 0
 *
 * It waits for the robot to say which clock it is on ("The robot clock"): a sample on
 * ubf/<robot>/clock (a simulator: stamp every sample with the newest simulated time heard
 * there) or on ubf/<robot>/time (a robot on wall time: stamp with this host's
 * CLOCK_MONOTONIC). Then it declares its liveliness token ubf/<robot>/alive/<name> -- with no
 * heartbeat it is judged by that token ("Liveliness and health") -- and publishes a fixed
 * reading on ubf/<robot>/sensor/range/<name> at -z Hz, the msgpack encoded by hand. The
 * robot's refusal notices about that key are printed on stderr.
 */

#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zenoh-pico.h>

static volatile sig_atomic_t stop = 0;
static void on_signal(int sig) {
    (void)sig;
    stop = 1;
}

/* ---- msgpack, by hand: just what this sensor sends and reads ---- */

typedef struct {
    uint8_t buf[256];
    size_t len;
} packer_t;

static void put_byte(packer_t *p, uint8_t b) { p->buf[p->len++] = b; }

static void put_be(packer_t *p, uint64_t v, int bytes) {
    for (int i = bytes - 1; i >= 0; --i) put_byte(p, (uint8_t)(v >> (8 * i)));
}

static void pack_map(packer_t *p, uint8_t n) { put_byte(p, (uint8_t)(0x80 | n)); } /* fixmap */

static void pack_str(packer_t *p, const char *s) {
    size_t n = strlen(s);
    if (n < 32) {
        put_byte(p, (uint8_t)(0xa0 | n)); /* fixstr */
    } else {
        put_byte(p, 0xd9); /* str 8 */
        put_byte(p, (uint8_t)n);
    }
    memcpy(p->buf + p->len, s, n);
    p->len += n;
}

static void pack_uint(packer_t *p, uint64_t v) {
    if (v < 128) {
        put_byte(p, (uint8_t)v); /* positive fixint */
    } else {
        put_byte(p, 0xcf); /* uint 64: any width is accepted */
        put_be(p, v, 8);
    }
}

static void pack_double(packer_t *p, double d) {
    uint64_t bits;
    memcpy(&bits, &d, sizeof bits);
    put_byte(p, 0xcb); /* float 64 */
    put_be(p, bits, 8);
}

/* A reader over one payload; every read checks the bounds (a malformed sample is ignored). */
typedef struct {
    const uint8_t *at;
    const uint8_t *end;
} reader_t;

static int take(reader_t *r, size_t n, const uint8_t **out) {
    if ((size_t)(r->end - r->at) < n) return -1;
    *out = r->at;
    r->at += n;
    return 0;
}

static int read_be(reader_t *r, int bytes, uint64_t *v) {
    const uint8_t *b;
    if (take(r, (size_t)bytes, &b) < 0) return -1;
    *v = 0;
    for (int i = 0; i < bytes; ++i) *v = (*v << 8) | b[i];
    return 0;
}

/* The length of a str/bin/array/map/ext whose header byte is `h`, or -1 if not one. */
static int container_len(reader_t *r, uint8_t h, uint64_t *n) {
    if ((h & 0xe0) == 0xa0) { *n = h & 0x1f; return 0; } /* fixstr */
    if ((h & 0xf0) == 0x90 || (h & 0xf0) == 0x80) { *n = h & 0x0f; return 0; } /* fixarray/map */
    switch (h) {
        case 0xd9: case 0xc4: return read_be(r, 1, n); /* str 8, bin 8 */
        case 0xda: case 0xc5: case 0xdc: case 0xde: return read_be(r, 2, n);
        case 0xdb: case 0xc6: case 0xdd: case 0xdf: return read_be(r, 4, n);
        default: return -1;
    }
}

static int skip_value(reader_t *r, int depth);

static int skip_n(reader_t *r, uint64_t n, int depth) {
    for (uint64_t i = 0; i < n; ++i)
        if (skip_value(r, depth + 1) < 0) return -1;
    return 0;
}

static int skip_value(reader_t *r, int depth) {
    const uint8_t *b;
    uint64_t n;
    if (depth > 16 || take(r, 1, &b) < 0) return -1;
    uint8_t h = b[0];
    if (h < 0x80 || h >= 0xe0 || h == 0xc0 || h == 0xc2 || h == 0xc3) return 0; /* fixint, nil, bool */
    switch (h) {
        case 0xcc: case 0xd0: return take(r, 1, &b);
        case 0xcd: case 0xd1: return take(r, 2, &b);
        case 0xce: case 0xd2: case 0xca: return take(r, 4, &b);
        case 0xcf: case 0xd3: case 0xcb: return take(r, 8, &b);
        case 0xd4: return take(r, 2, &b); /* fixext 1 */
        case 0xd5: return take(r, 3, &b);
        case 0xd6: return take(r, 5, &b);
        case 0xd7: return take(r, 9, &b);
        case 0xd8: return take(r, 17, &b);
        case 0xc7: case 0xc8: case 0xc9: /* ext 8/16/32: length, type, data */
            if (read_be(r, h == 0xc7 ? 1 : h == 0xc8 ? 2 : 4, &n) < 0) return -1;
            return take(r, (size_t)n + 1, &b);
    }
    if (container_len(r, h, &n) < 0) return -1;
    if ((h & 0xf0) == 0x80 || h == 0xde || h == 0xdf) return skip_n(r, 2 * n, depth);
    if ((h & 0xf0) == 0x90 || h == 0xdc || h == 0xdd) return skip_n(r, n, depth);
    return take(r, (size_t)n, &b); /* str or bin */
}

/* The top-level map's "stamp_ns" if it is a non-negative integer: 0 found, -1 not. */
static int find_stamp_ns(const uint8_t *data, size_t len, uint64_t *stamp) {
    reader_t r = {data, data + len};
    const uint8_t *b;
    uint64_t entries, klen;
    if (take(&r, 1, &b) < 0 || container_len(&r, b[0], &entries) < 0) return -1;
    if (!((b[0] & 0xf0) == 0x80 || b[0] == 0xde || b[0] == 0xdf)) return -1; /* not a map */
    for (uint64_t i = 0; i < entries; ++i) {
        const uint8_t *key;
        if (take(&r, 1, &b) < 0 || container_len(&r, b[0], &klen) < 0 || take(&r, (size_t)klen, &key) < 0)
            return -1;
        if (klen == 8 && memcmp(key, "stamp_ns", 8) == 0) {
            if (take(&r, 1, &b) < 0) return -1;
            if (b[0] < 0x80) { *stamp = b[0]; return 0; }
            if (b[0] >= 0xcc && b[0] <= 0xcf) return read_be(&r, 1 << (b[0] - 0xcc), stamp);
            return -1;
        }
        if (skip_value(&r, 0) < 0) return -1;
    }
    return -1;
}

/* ---- the robot clock ---- */

static volatile uint64_t sim_ns = 0;  /* the newest simulated time heard (it starts at 0) */
static volatile int simulated = 0;    /* a clock sample came: the robot runs on simulated time */
static volatile int told = 0;         /* the robot said which clock (clock or time) */

static void on_clock(z_loaned_sample_t *sample, void *ctx) {
    (void)ctx;
    z_owned_slice_t slice;
    uint64_t stamp;
    if (z_bytes_to_slice(z_sample_payload(sample), &slice) < 0) return;
    if (find_stamp_ns(z_slice_data(z_loan(slice)), z_slice_len(z_loan(slice)), &stamp) == 0) {
        sim_ns = stamp;
        simulated = 1;
        told = 1;
    }
    z_drop(z_move(slice));
}

static void on_time(z_loaned_sample_t *sample, void *ctx) {
    (void)sample;
    (void)ctx;
    told = 1;
}

static char refused_key[160];

static void on_refused(z_loaned_sample_t *sample, void *ctx) {
    (void)ctx;
    z_owned_slice_t slice;
    if (z_bytes_to_slice(z_sample_payload(sample), &slice) < 0) return;
    /* the notice's reason and detail are msgpack strings; a C sensor would decode them as
       above -- here it says that one came and how long it is */
    fprintf(stderr, "the robot refuses our samples (a notice of %zu bytes on %s): run "
            "`python -m ubf_async.inspector conform NAME` to see why\n",
            z_slice_len(z_loan(slice)), refused_key);
    z_drop(z_move(slice));
}

static uint64_t monotonic_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static int declare_sub(const z_loaned_session_t *s, z_owned_subscriber_t *sub, const char *key,
                       void (*handler)(z_loaned_sample_t *, void *)) {
    z_view_keyexpr_t ke;
    z_owned_closure_sample_t callback;
    if (z_view_keyexpr_from_str(&ke, key) < 0) return -1;
    z_closure(&callback, handler, NULL, NULL);
    return z_declare_subscriber(s, sub, z_loan(ke), z_move(callback), NULL);
}

static void usage(const char *argv0) {
    fprintf(stderr,
            "usage: %s -e ENDPOINT [-r ROBOT] [-n NAME] [-d RANGE_MM] [-z RATE_HZ] [-c COUNT] [-w CLOCK_WAIT_S]\n"
            "  -e  the robot's zenoh endpoint, e.g. tcp/127.0.0.1:7447 (a zenoh-pico client connects to it)\n"
            "  -r  the robot's name (default mini); -n this sensor's name: source range/NAME (default ext)\n"
            "  -d  the reading in mm (default 250); -z samples a second (default 20); -c stop after COUNT (0: never)\n"
            "  -w  seconds to wait for the robot to say which clock it is on (default 30)\n",
            argv0);
}

int main(int argc, char **argv) {
    const char *endpoint = NULL, *robot = "mini", *name = "ext";
    long range_mm = 250, count = 0;
    double rate_hz = 20.0, clock_wait_s = 30.0;
    int opt;
    while ((opt = getopt(argc, argv, "e:r:n:d:z:c:w:h")) != -1) {
        switch (opt) {
            case 'e': endpoint = optarg; break;
            case 'r': robot = optarg; break;
            case 'n': name = optarg; break;
            case 'd': range_mm = strtol(optarg, NULL, 10); break;
            case 'z': rate_hz = strtod(optarg, NULL); break;
            case 'c': count = strtol(optarg, NULL, 10); break;
            case 'w': clock_wait_s = strtod(optarg, NULL); break;
            default: usage(argv[0]); return opt == 'h' ? 0 : 2;
        }
    }
    if (endpoint == NULL || rate_hz <= 0.0 || range_mm < 0 || range_mm > 65535 || strlen(name) > 64 ||
        strlen(robot) > 64) {
        usage(argv[0]);
        return 2;
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);

    z_owned_config_t config;
    z_config_default(&config);
    zp_config_insert(z_loan_mut(config), Z_CONFIG_MODE_KEY, "client");
    zp_config_insert(z_loan_mut(config), Z_CONFIG_CONNECT_KEY, endpoint);
    z_owned_session_t s;
    if (z_open(&s, z_move(config), NULL) < 0) {
        fprintf(stderr, "nothing answers at %s: is the robot running?\n", endpoint);
        return 1;
    }

    char key[160];
    z_owned_subscriber_t clock_sub, time_sub, refused_sub;
    snprintf(key, sizeof key, "ubf/%s/clock", robot);
    declare_sub(z_loan(s), &clock_sub, key, on_clock);
    snprintf(key, sizeof key, "ubf/%s/time", robot);
    declare_sub(z_loan(s), &time_sub, key, on_time);
    for (double waited = 0.0; !told && waited < clock_wait_s && !stop; waited += 0.01) z_sleep_ms(10);
    if (!told)
        printf("nothing on ubf/%s/clock or ubf/%s/time within %gs: stamping with CLOCK_MONOTONIC\n", robot, robot,
               clock_wait_s);
    else if (simulated)
        printf("stamping with the simulated time on ubf/%s/clock\n", robot);
    else
        printf("the robot is on wall time (ubf/%s/time): stamping with CLOCK_MONOTONIC\n", robot);
    fflush(stdout);
    z_drop(z_move(time_sub));

    snprintf(refused_key, sizeof refused_key, "ubf/%s/refused/sensor/range/%s", robot, name);
    declare_sub(z_loan(s), &refused_sub, refused_key, on_refused);

    z_owned_liveliness_token_t token;
    z_view_keyexpr_t token_ke, pub_ke;
    char token_key[160], pub_key[160];
    snprintf(token_key, sizeof token_key, "ubf/%s/alive/%s", robot, name);
    snprintf(pub_key, sizeof pub_key, "ubf/%s/sensor/range/%s", robot, name);
    z_owned_publisher_t pub;
    if (z_view_keyexpr_from_str(&token_ke, token_key) < 0 || z_view_keyexpr_from_str(&pub_ke, pub_key) < 0) {
        fprintf(stderr, "%s: not a valid name segment (no / * $ ? #)\n", name);
        return 2;
    }
    if (z_liveliness_declare_token(z_loan(s), &token, z_loan(token_ke), NULL) < 0 ||
        z_declare_publisher(z_loan(s), &pub, z_loan(pub_ke), NULL) < 0) {
        fprintf(stderr, "cannot declare the token or the publisher\n");
        return 1;
    }
    printf("publishing %s\n", pub_key);
    fflush(stdout);

    double period_s = 1.0 / rate_hz;
    for (uint64_t seq = 1; !stop && (count == 0 || seq <= (uint64_t)count); ++seq) {
        packer_t p = {.len = 0};
        pack_map(&p, 6);
        pack_str(&p, "schema"); pack_str(&p, "range"); /* a schema the robot knows */
        pack_str(&p, "v"); pack_uint(&p, 1);            /* protocol version */
        pack_str(&p, "stamp_ns"); pack_uint(&p, simulated ? sim_ns : monotonic_ns());
        pack_str(&p, "seq"); pack_uint(&p, seq);        /* increasing per publisher */
        pack_str(&p, "period_s"); pack_double(&p, period_s); /* when the robot calls us stale */
        pack_str(&p, "data");
        pack_map(&p, 3);
        pack_str(&p, "range_mm"); pack_uint(&p, (uint64_t)range_mm);
        pack_str(&p, "status"); pack_str(&p, "ok");
        pack_str(&p, "model"); pack_str(&p, "ir-10-80");
        z_owned_bytes_t payload;
        z_bytes_copy_from_buf(&payload, p.buf, p.len);
        z_publisher_put(z_loan(pub), z_move(payload), NULL);
        z_sleep_ms((size_t)(period_s * 1000.0));
    }

    z_drop(z_move(pub));
    z_drop(z_move(token)); /* a clean goodbye: the robot reads us as left, not gone */
    z_drop(z_move(refused_sub));
    z_drop(z_move(clock_sub));
    z_drop(z_move(s));
    return 0;
}
