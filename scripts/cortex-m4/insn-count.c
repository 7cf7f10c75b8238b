/*
 * A QEMU TCG plugin that counts the guest instructions executed between two marker addresses,
 * exactly: every executed instruction is counted by a callback that TCG inserts before it, so a
 * region is counted instruction by instruction whatever the translation blocks look like.
 *
 *   qemu-system-arm ... -plugin ./insn-count.so,begin=0x1234,end=0x1250[,profile=FILE]
 *
 * A region opens when the instruction at `begin` executes and closes when the instruction at
 * `end` executes; counted are the instructions executed after `begin`'s first instruction up to
 * and including the one before `end`'s (so the marker functions' own bodies are not counted, but
 * the call to `end` is: the guest calibrates that away with an empty region). Each closed region
 * prints one line on stderr, "insn-count region N: COUNT", in guest order with the guest's own
 * semihosting output. With profile=FILE, the plugin also writes, at exit, how many instructions
 * of all regions each guest address executed ("ADDRESS COUNT" per line), for attributing the
 * cost to functions and source lines (scripts/cortex-m4-cost.sh --profile); only=FILE
 * restricts that histogram to the regions FILE lists, one number per line (regions are numbered
 * from 0 in the order they close).
 *
 * An instruction in a Thumb IT block whose condition fails is counted: the Cortex-M4 executes it
 * as a no-op, and QEMU's -icount counts it too.
 *
 * Built against QEMU's plugin API version 1 (QEMU 7.2, Debian 12), which Debian ships no header
 * for: the few declarations below follow include/qemu/qemu-plugin.h of that version.
 */
#include <inttypes.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* --- QEMU plugin API, version 1: only what this plugin uses. -------------------------------- */
typedef uint64_t qemu_plugin_id_t;
typedef struct qemu_info_t qemu_info_t; /* passed to install; not read here */
struct qemu_plugin_tb;
struct qemu_plugin_insn;
enum qemu_plugin_cb_flags { QEMU_PLUGIN_CB_NO_REGS, QEMU_PLUGIN_CB_R_REGS, QEMU_PLUGIN_CB_RW_REGS };
typedef void (*qemu_plugin_udata_cb_t)(qemu_plugin_id_t id, void *userdata);
typedef void (*qemu_plugin_vcpu_udata_cb_t)(unsigned int vcpu_index, void *userdata);
typedef void (*qemu_plugin_vcpu_tb_trans_cb_t)(qemu_plugin_id_t id, struct qemu_plugin_tb *tb);
void qemu_plugin_register_vcpu_tb_trans_cb(qemu_plugin_id_t id, qemu_plugin_vcpu_tb_trans_cb_t cb);
void qemu_plugin_register_vcpu_insn_exec_cb(struct qemu_plugin_insn *insn,
                                            qemu_plugin_vcpu_udata_cb_t cb,
                                            enum qemu_plugin_cb_flags flags, void *userdata);
size_t qemu_plugin_tb_n_insns(const struct qemu_plugin_tb *tb);
struct qemu_plugin_insn *qemu_plugin_tb_get_insn(const struct qemu_plugin_tb *tb, size_t idx);
uint64_t qemu_plugin_insn_vaddr(const struct qemu_plugin_insn *insn);
void qemu_plugin_register_atexit_cb(qemu_plugin_id_t id, qemu_plugin_udata_cb_t cb, void *userdata);
__attribute__((visibility("default"))) int qemu_plugin_version = 1;
/* ----------------------------------------------------------------------------------------- */

/* Guest code addresses below this are profiled per instruction (the program's 256 KiB). */
#define PROFILED_BYTES (256u * 1024u)

static uint64_t begin_addr = UINT64_MAX;
static uint64_t end_addr = UINT64_MAX;
static bool counting;
static uint64_t count;
static uint64_t regions;
static const char *profile_path;
/* The regions to profile, one bit each; NULL: all. */
static uint8_t *profiled;
static uint64_t profiled_count;
/* Instructions counted per guest halfword address (Thumb instructions are 2-byte aligned). */
static uint64_t *histogram;

static void on_insn(unsigned int vcpu, void *pc)
{
    (void)vcpu;
    if (counting) {
        count++;
        if (histogram && (!profiled || (regions < profiled_count && (profiled[regions / 8] >> (regions % 8)) & 1))) {
            histogram[(uintptr_t)pc >> 1]++;
        }
    }
}

static void on_begin(unsigned int vcpu, void *pc)
{
    (void)vcpu;
    (void)pc;
    if (counting) {
        fprintf(stderr, "insn-count: region %" PRIu64 " opened twice\n", regions);
        exit(3);
    }
    counting = true;
    count = 0;
}

static void on_end(unsigned int vcpu, void *pc)
{
    (void)vcpu;
    (void)pc;
    if (!counting) {
        fprintf(stderr, "insn-count: region %" PRIu64 " closed without being opened\n", regions);
        exit(3);
    }
    counting = false;
    fprintf(stderr, "insn-count region %" PRIu64 ": %" PRIu64 "\n", regions, count);
    regions++;
}

static void on_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t pc = qemu_plugin_insn_vaddr(insn);
        qemu_plugin_vcpu_udata_cb_t cb = on_insn;
        if (pc == begin_addr) {
            cb = on_begin;
        } else if (pc == end_addr) {
            cb = on_end;
        } else if (histogram && pc >= PROFILED_BYTES) {
            fprintf(stderr, "insn-count: instruction at 0x%" PRIx64 " outside the profiled range\n", pc);
            exit(3);
        }
        qemu_plugin_register_vcpu_insn_exec_cb(insn, cb, QEMU_PLUGIN_CB_NO_REGS,
                                               (void *)(uintptr_t)pc);
    }
}

static void on_exit_(qemu_plugin_id_t id, void *userdata)
{
    (void)id;
    (void)userdata;
    if (counting) {
        fprintf(stderr, "insn-count: region %" PRIu64 " still open at exit\n", regions);
    }
    if (histogram) {
        FILE *out = fopen(profile_path, "w");
        if (!out) {
            perror(profile_path);
            return;
        }
        for (uint64_t half = 0; half < PROFILED_BYTES / 2; half++) {
            if (histogram[half]) {
                fprintf(out, "%08" PRIx64 " %" PRIu64 "\n", half << 1, histogram[half]);
            }
        }
        fclose(out);
    }
}

static bool parse_address(const char *text, uint64_t *out)
{
    char *rest;
    unsigned long long value = strtoull(text, &rest, 0);
    if (*text == '\0' || *rest != '\0') {
        return false;
    }
    /* Thumb function symbols have bit 0 set; the instruction is at the even address. */
    *out = value & ~1ull;
    return true;
}

/* Reads the region numbers of only=FILE into the `profiled` bitmap. */
static bool read_regions(const char *path)
{
    FILE *in = fopen(path, "r");
    if (!in) {
        perror(path);
        return false;
    }
    unsigned long long region;
    while (fscanf(in, "%llu", &region) == 1) {
        if (region >= profiled_count) {
            uint64_t count = (region + 1) * 2;
            uint8_t *grown = realloc(profiled, (count + 7) / 8);
            if (!grown) {
                fclose(in);
                return false;
            }
            memset(grown + (profiled_count + 7) / 8, 0, (count + 7) / 8 - (profiled_count + 7) / 8);
            profiled = grown;
            profiled_count = count;
        }
        profiled[region / 8] |= (uint8_t)(1u << (region % 8));
    }
    bool ok = feof(in);
    fclose(in);
    return ok;
}

__attribute__((visibility("default"))) int qemu_plugin_install(qemu_plugin_id_t id,
                                                               const qemu_info_t *info, int argc,
                                                               char **argv)
{
    (void)info;
    for (int i = 0; i < argc; i++) {
        const char *arg = argv[i];
        bool ok = true;
        if (strncmp(arg, "begin=", 6) == 0) {
            ok = parse_address(arg + 6, &begin_addr);
        } else if (strncmp(arg, "end=", 4) == 0) {
            ok = parse_address(arg + 4, &end_addr);
        } else if (strncmp(arg, "profile=", 8) == 0) {
            profile_path = arg + 8;
        } else if (strncmp(arg, "only=", 5) == 0) {
            ok = read_regions(arg + 5);
        } else {
            ok = false;
        }
        if (!ok) {
            fprintf(stderr, "insn-count: bad argument '%s' (begin=ADDR, end=ADDR, profile=FILE, only=FILE)\n", arg);
            return -1;
        }
    }
    if (begin_addr == UINT64_MAX || end_addr == UINT64_MAX || begin_addr == end_addr) {
        fprintf(stderr, "insn-count: needs begin=ADDR and end=ADDR, two different addresses\n");
        return -1;
    }
    if (profile_path) {
        histogram = calloc(PROFILED_BYTES / 2, sizeof *histogram);
        if (!histogram) {
            return -1;
        }
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
    qemu_plugin_register_atexit_cb(id, on_exit_, NULL);
    return 0;
}
