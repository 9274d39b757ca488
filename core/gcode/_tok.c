/* Compiled text helpers of mtcomp.gcode: a one-pass tokenizer (the twin of
 * tokens._tokenise, tokens._comment_spans and textops.parse_decimals) and the byte splice of
 * textops.splice.  The Python code is the reference and the fallback; the parity tests hold
 * the two to the same bytes and the same float bits.
 *
 * Input of the tokenizer: the program bytes with comments, '%' lines and block-delete slashes
 * already blanked.  Written by hand because no library tokenises a byte buffer into address
 * words in one pass.  Plain C99, no Python headers: loaded through ctypes.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>

static inline int is_letter(uint8_t c) { return (uint8_t)((c | 32) - 97) < 26; }
/* + - . and digits (43..57 without ',' and '/') */
static inline int is_num(uint8_t c) { return (uint8_t)(c - 43) < 15 && c != 44 && c != 47; }
static inline int is_blank(uint8_t c) { return c == 32 || (uint8_t)(c - 9) < 5; }

/* Eight bytes at p as a little-endian word (memcpy: no alignment needed). */
static inline uint64_t load8(const uint8_t *p)
{
    uint64_t x;
    memcpy(&x, p, 8);
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    x = __builtin_bswap64(x);
#endif
    return x;
}

/* Number of leading digit bytes (0..8) of the eight bytes x (first byte lowest).  A byte is a
 * digit if its xor with '0' is 0..9: high nibble zero and +6 not carrying into it; a carry
 * from a non-digit byte only reaches the bytes after it. */
static inline int digit_run8(uint64_t x)
{
    uint64_t a = x ^ 0x3030303030303030ULL;
    uint64_t bad = (a | (a + 0x0606060606060606ULL)) & 0xF0F0F0F0F0F0F0F0ULL;
    return bad ? __builtin_ctzll(bad) >> 3 : 8;
}

/* Value of the first k (1..7) bytes of x, all digits, as an integer (the bytes after them
 * replaced by leading '0's; the usual three multiply-shift steps over eight digits). */
static inline uint64_t digits_value8(uint64_t x, int k)
{
    x = (x << (8 * (8 - k))) | (0x3030303030303030ULL >> (8 * k));
    x -= 0x3030303030303030ULL;
    x = (x * 10) + (x >> 8);
    x = (((x & 0x000000FF000000FFULL) * 0x000F424000000064ULL) +
         (((x >> 16) & 0x000000FF000000FFULL) * 0x0000271000000001ULL)) >> 32;
    return x;
}

static const uint64_t POW10I[9] = {1, 10, 100, 1000, 10000, 100000, 1000000, 10000000, 100000000};

static const double POW10[23] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11,
                                 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

/* Number of letters and of maximal runs of number characters.  Written without a carried
 * state (a run starts where a number character follows a non-number one) so that the compiler
 * vectorises it. */
void mtc_count(const uint8_t *c, int64_t n, int64_t *n_letters, int64_t *n_runs)
{
    int64_t nl = 0, nr = 0, i0 = 0;
    while (i0 < n) {                       /* blocks of 2**20 bytes: 32-bit counters vectorise */
        int64_t i1 = n - i0 > (1 << 20) ? i0 + (1 << 20) : n;
        uint32_t a = 0, b = 0;
        for (int64_t i = i0 > 0 ? i0 : 1; i < i1; i++) {
            a += is_letter(c[i]);
            b += is_num(c[i]) & !is_num(c[i - 1]);
        }
        nl += a;
        nr += b;
        i0 = i1;
    }
    if (n > 0) {
        nl += is_letter(c[0]);
        nr += is_num(c[0]);
    }
    *n_letters = nl;
    *n_runs = nr;
}

/* Value of the number text c[s:e] (validated or not: garbage in, some finite or NaN value out;
 * the caller validates before using it).  Correctly rounded: an exact integer mantissa of at
 * most 15 digits divided once by an exact power of ten, as parse_decimals does; longer numbers
 * through strtod (correctly rounded in glibc and musl, as Python's float()). */
static double number(const uint8_t *c, int64_t s, int64_t e, int64_t dot)
{
    int neg = c[s] == '-';
    int64_t i0 = s + (c[s] == '-' || c[s] == '+');
    int64_t iend = dot >= 0 ? dot : e;
    int64_t ilen = iend - i0, flen = dot >= 0 ? e - dot - 1 : 0;
    if (ilen <= 8 && flen <= 8 && ilen + flen <= 15) {
        uint64_t m = 0;
        for (int64_t k = i0; k < iend; k++) m = m * 10 + (uint64_t)(c[k] - '0');
        for (int64_t k = iend + 1; k < e; k++) m = m * 10 + (uint64_t)(c[k] - '0');
        double v = (double)m / POW10[flen];
        return neg ? -v : v;
    }
    char small[64];
    char *buf = (e - s < 63) ? small : (char *)malloc((size_t)(e - s + 1));
    if (!buf) return 0.0 / 0.0;
    memcpy(buf, c + s, (size_t)(e - s));
    buf[e - s] = 0;
    double v = strtod(buf, NULL);
    if (buf != small) free(buf);
    return v;
}

/* The common number run at c[j] (unsigned; the caller has checked j + 17 <= n), eight bytes at a
 * time: up to 7 digits [. up to 7 digits].  1 with its end in *end, its point in *dot (-1:
 * none), its number of digits in *nd and its value (the integer mantissa over an exact power
 * of ten: correctly rounded, as strtod) in *value; 0 where a part has 8 digits or more (the
 * callers' byte loops take those).  What follows the run is the caller's to judge. */
static inline int common_number8(const uint8_t *c, int64_t j, int64_t *end, int64_t *dot, int *nd,
                                 double *value)
{
    uint64_t x = load8(c + j);
    int k1 = digit_run8(x), k2 = 0;
    if (k1 >= 8) return 0;
    int64_t e = j + k1, d = -1;
    uint64_t m = k1 ? digits_value8(x, k1) : 0;
    if (c[e] == '.') {
        uint64_t y = load8(c + e + 1);
        k2 = digit_run8(y);
        if (k2 >= 8) return 0;
        d = e;
        m = m * POW10I[k2] + (k2 ? digits_value8(y, k2) : 0);
        e += 1 + k2;
    }
    *end = e;
    *dot = d;
    *nd = k1 + k2;
    *value = (double)m / POW10[k2];
    return 1;
}

/* Letters (position, 0-based line), number runs [start, end) with the position of their point
 * (-1: none; the last one if several), whether they hold more than one point, and their value;
 * *sign_at: first '+'/'-' preceded by a number character (-1: none); *bad_at: first byte that is
 * no letter, number character or blank (-1: none); dup_line[26]: per letter a-z the first
 * 0-based line where it appears twice (-1: none).  Arrays sized by mtc_count; positions are
 * int32 (the caller refuses programs of 2 GB and more).  checks[0]: 1 if every run starts
 * right after the letter of the same index and there are as many of each (parse's test for
 * blanks or missing numbers), checks[1]: the first run with more than one point or without a
 * digit (-1: none), as parse's `badnum`.  let: each letter's index 0..25 (a-z, either case:
 * parse's `wlet`), let_count[26]: the number of words of each letter.  dot, two, let and
 * let_count may be NULL (not written). */
void mtc_tokenise(const uint8_t *c, int64_t n, int32_t *lp, int32_t *wline, int32_t *rs,
                  int32_t *re, int32_t *dot, uint8_t *two, double *value, int64_t *sign_at,
                  int64_t *bad_at, int32_t *dup_line, int64_t *checks, int8_t *let,
                  int64_t *let_count)
{
    int64_t adjacent = 1, badnum = -1;
    /* classes: 0 other, 1 blank, 2 letter, 3 number character, 4 newline */
    uint8_t cls[256];
    for (int k = 0; k < 256; k++)
        cls[k] = is_num((uint8_t)k) ? 3 : is_letter((uint8_t)k) ? 2 : k == '\n' ? 4 : is_blank((uint8_t)k) ? 1 : 0;
    int64_t nl = 0, nr = -1, line = 0;
    uint32_t seen = 0;                  /* letters of the current line */
    for (int k = 0; k < 26; k++) dup_line[k] = -1;
    if (let_count) for (int k = 0; k < 26; k++) let_count[k] = 0;
    int64_t sg = -1, bad = -1;
    int64_t i = 0;
    while (i < n) {
        uint8_t ch = c[i];
        uint8_t k = cls[ch];
        if (k == 3) {
            /* the common run first, eight bytes at a time: [sign] up to 7 digits [. up to 7
             * digits], ended by no number character; the same integer mantissa, value and
             * bookkeeping as the byte loop below, which takes every other run */
            int64_t j0 = i + (ch == '-' || ch == '+');
            int64_t e, d;
            int nd8;
            double v;
            if (j0 + 17 <= n && common_number8(c, j0, &e, &d, &nd8, &v)) {
                uint8_t t = c[e];
                if (nd8 > 0 && t != '.' && t != '-' && t != '+') {
                    nr++;
                    if (nr >= nl || lp[nr] != i - 1) adjacent = 0;
                    rs[nr] = (int32_t)i;
                    re[nr] = (int32_t)e;
                    if (dot) dot[nr] = (int32_t)d;
                    if (two) two[nr] = 0;
                    value[nr] = ch == '-' ? -v : v;
                    i = e;
                    continue;
                }
            }
        }
        if (k == 3) {
            /* one number run, its value read on the way (the same arithmetic as number()) */
            int64_t s = i, d = -1;
            int pts = 0, inner = 0;     /* points; an inner sign (number() then decides) */
            uint64_t m = 0;
            int64_t nd = 0;
            if (ch == '-' || ch == '+') i++;
            for (; i < n; i++) {
                uint8_t x = c[i];
                unsigned dg = (unsigned)x - '0';
                if (dg < 10) { m = m * 10 + dg; nd++; continue; }
                if (x == '.') { pts++; d = i; continue; }
                if (x == '-' || x == '+') { if (sg < 0) sg = i; inner = 1; continue; }
                break;
            }
            nr++;
            if (nr >= nl || lp[nr] != s - 1) adjacent = 0;
            {
                int64_t ndig = (i - s) - (d >= 0) - (c[s] == '-' || c[s] == '+');
                if (badnum < 0 && (pts > 1 || ndig < 1)) badnum = nr;
            }
            rs[nr] = (int32_t)s;
            re[nr] = (int32_t)i;
            if (dot) dot[nr] = (int32_t)d;
            if (two) two[nr] = (uint8_t)(pts > 1);
            int64_t flen = d >= 0 ? i - d - 1 : 0, ilen = nd - flen;
            if (!inner && pts <= 1 && ilen <= 8 && flen <= 8 && nd <= 15) {
                double v = (double)m / POW10[flen];
                value[nr] = c[s] == '-' ? -v : v;
            } else {
                value[nr] = number(c, s, i, d);
            }
            continue;
        }
        i++;
        if (k == 2) {
            uint32_t bit = 1u << ((ch | 32) - 97);
            if ((seen & bit) && dup_line[(ch | 32) - 97] < 0) dup_line[(ch | 32) - 97] = (int32_t)line;
            seen |= bit;
            lp[nl] = (int32_t)(i - 1);
            wline[nl] = (int32_t)line;
            if (let) let[nl] = (int8_t)((ch | 32) - 97);
            if (let_count) let_count[(ch | 32) - 97]++;
            nl++;
        } else if (k == 4) {
            line++;
            seen = 0;
        } else if (k == 0 && bad < 0) {
            bad = i - 1;
        }
    }
    *sign_at = sg;
    *bad_at = bad;
    checks[0] = adjacent && nr + 1 == nl;
    checks[1] = badnum;
}

/* Whether any byte of the eight bytes x equals b (the classic zero-byte test on x ^ b*0x01..:
 * exact as to whether there is one). */
static inline int has_byte8(uint64_t x, uint8_t b)
{
    uint64_t v = x ^ (0x0101010101010101ULL * b);
    return ((v - 0x0101010101010101ULL) & ~v & 0x8080808080808080ULL) != 0;
}

/* The program bytes `d` copied into `code` (n bytes, written whole) with the comments blanked:
 * "( ... )" closed on its line without a nested '(' (an unclosed one stays, to be reported),
 * ';' to the end of the line, and lines starting with '%' (`first`: where the first line
 * starts, after a byte-order mark); the same spans as tokens._comment_spans.  Eight bytes
 * without '(' ';' '%' are copied at once (most of a program: comments are rare), everything
 * else byte by byte.  Returns the number of comments. */
int64_t mtc_copy_blank_comments(const uint8_t *d, uint8_t *code, int64_t n, int64_t first)
{
    int64_t i = 0, count = 0;
    while (i < n) {
        if (i + 8 <= n) {
            uint64_t x;
            memcpy(&x, d + i, 8);
            if (!has_byte8(x, '(') && !has_byte8(x, ';') && !has_byte8(x, '%')) {
                memcpy(code + i, &x, 8);
                i += 8;
                continue;
            }
        }
        uint8_t ch = d[i];
        if (ch == '(') {
            int64_t j = i + 1;
            while (j < n && d[j] != ')' && d[j] != '(' && d[j] != '\n') j++;
            if (j < n && d[j] == ')') {
                memset(code + i, 32, (size_t)(j + 1 - i));
                count++;
                i = j + 1;
                continue;
            }
        } else if (ch == ';' || (ch == '%' && (i <= first || d[i - 1] == '\n'))) {
            int64_t j = i;
            while (j < n && d[j] != '\n') j++;
            memset(code + i, 32, (size_t)(j - i));
            count++;
            i = j;
            continue;
        }
        code[i] = ch;
        i++;
    }
    return count;
}

/* Whether the ASCII text c[0:n] holds a match of gcode.flow's _HAS_FLOW pattern, searched
 * as re.search does: "[Mm][ \t]*0*9[789](?![0-9.])" (an M97/M98/M99 word) or
 * "[Oo][ \t]*(?:<[^>\n]*>|\d+)[ \t]*[Cc][Aa][Ll][Ll]" (an o-word call).  Each part of the
 * pattern matches one way only (its classes are disjoint from what follows), so trying each M
 * and O in turn is the search.  Eight bytes without M m O o are passed over at once. */
static inline int is_digit(uint8_t c) { return (unsigned)c - '0' < 10; }

static int flow_m_at(const uint8_t *c, int64_t n, int64_t j)
{
    while (j < n && (c[j] == ' ' || c[j] == '\t')) j++;
    while (j < n && c[j] == '0') j++;
    if (j + 1 >= n || c[j] != '9' || (unsigned)c[j + 1] - '7' > 2) return 0;
    return j + 2 >= n || !(is_digit(c[j + 2]) || c[j + 2] == '.');
}

static int flow_o_at(const uint8_t *c, int64_t n, int64_t j)
{
    while (j < n && (c[j] == ' ' || c[j] == '\t')) j++;
    if (j < n && c[j] == '<') {
        j++;
        while (j < n && c[j] != '>' && c[j] != '\n') j++;
        if (j >= n || c[j] != '>') return 0;
        j++;
    } else if (j < n && is_digit(c[j])) {
        while (j < n && is_digit(c[j])) j++;
    } else {
        return 0;
    }
    while (j < n && (c[j] == ' ' || c[j] == '\t')) j++;
    return j + 4 <= n && (c[j] | 32) == 'c' && (c[j + 1] | 32) == 'a' && (c[j + 2] | 32) == 'l'
           && (c[j + 3] | 32) == 'l';
}

int64_t mtc_has_flow(const uint8_t *c, int64_t n)
{
    int64_t i = 0;
    while (i < n) {
        if (i + 8 <= n) {
            uint64_t x;
            memcpy(&x, c + i, 8);
            x |= 0x2020202020202020ULL;           /* M -> m, O -> o (and no other byte) */
            if (!has_byte8(x, 'm') && !has_byte8(x, 'o')) {
                i += 8;
                continue;
            }
        }
        uint8_t ch = c[i] | 32;
        if (ch == 'm' && (c[i] == 'M' || c[i] == 'm') && flow_m_at(c, n, i + 1)) return 1;
        if (ch == 'o' && (c[i] == 'O' || c[i] == 'o') && flow_o_at(c, n, i + 1)) return 1;
        i++;
    }
    return 0;
}

/* The counts of the rewrite (rewrite_with_lines): out = Cc ((rows, n) float) with dK ((m, n))
 * added to row 1 + kk[j] (kk ascending; kk NULL: row 1 + j), NaN as 0, as int64: numpy's
 * `Cc[1 + kk] += dK; nan_to_num(Cc).astype(int64)` in one pass.  Returns 0, or -1 (out not
 * to be used) if kk is not ascending or in range, or a sum is infinite or not below 2**63 in
 * magnitude (numpy's conversion of those differs between platforms: the caller's path). */
int64_t mtc_add_counts(const double *Cc, int64_t rows, int64_t n, const double *dK,
                       const int64_t *kk, int64_t m, int64_t *out)
{
    const double lim = 9223372036854775808.0;
    int64_t j = 0;
    if (!kk && m != rows - 1) return -1;
    for (int64_t r = 0; r < rows; r++) {
        const double *d = NULL;
        if (r > 0 && j < m && (kk ? kk[j] == r - 1 : 1)) {
            if (kk && j > 0 && kk[j] <= kk[j - 1]) return -1;
            d = dK + j * n;
            j++;
        }
        for (int64_t k = 0; k < n; k++) {
            double v = Cc[r * n + k];
            if (d) v += d[k];
            if (v != v) { out[r * n + k] = 0; continue; }
            if (!(v < lim && v > -lim)) return -1;
            out[r * n + k] = (int64_t)v;
        }
    }
    return j == m ? 0 : -1;
}

/* Splice: out = orig with the m edits applied (sorted by position, removed ranges not
 * overlapping, checked by the caller): before edit i the original bytes up to pos[i], then
 * src[src_off[i] : src_off[i] + src_len[i]]; orig[pos[i]:stop[i]] is dropped.  `out` holds
 * the exact result size.  The compiled twin of the gather in textops.splice. */
void mtc_splice(const uint8_t *orig, int64_t n_orig, const uint8_t *src, const int64_t *pos,
                const int64_t *stop, const int64_t *src_off, const int64_t *src_len, int64_t m,
                uint8_t *out)
{
    int64_t prev = 0, o = 0;
    for (int64_t i = 0; i < m; i++) {
        if (pos[i] > prev) {
            memcpy(out + o, orig + prev, (size_t)(pos[i] - prev));
            o += pos[i] - prev;
        }
        if (src_len[i] > 0) {
            memcpy(out + o, src + src_off[i], (size_t)src_len[i]);
            o += src_len[i];
        }
        if (stop[i] > prev) prev = stop[i];
    }
    if (n_orig > prev) memcpy(out + o, orig + prev, (size_t)(n_orig - prev));
}

/* mtc_splice in place: `buf` holds the n_orig original bytes and has room for max(n_orig,
 * total), total the result's size.  Each kept segment of the original moves to its place
 * (those moving towards the start front to back, then those moving towards the end back to
 * front: neither overwrites a segment still to move nor one already placed), then the
 * inserted texts go into the gaps.  Returns 0, or -1 if out of memory (nothing changed). */
int64_t mtc_splice_inplace(uint8_t *buf, int64_t n_orig, const uint8_t *src, const int64_t *pos,
                           const int64_t *stop, const int64_t *src_off, const int64_t *src_len,
                           int64_t m)
{
    int64_t *a = malloc((size_t)(m + 1) * 3 * sizeof(int64_t));
    if (!a) return -1;
    int64_t *from = a, *to = a + m + 1, *len = a + 2 * (m + 1);
    int64_t prev = 0, o = 0;
    for (int64_t i = 0; i <= m; i++) {          /* segment i before edit i; m: the tail */
        int64_t e = i < m ? pos[i] : n_orig;
        from[i] = prev;
        len[i] = e > prev ? e - prev : 0;
        to[i] = o;
        o += len[i];
        if (i < m) {
            o += src_len[i] > 0 ? src_len[i] : 0;
            if (stop[i] > prev) prev = stop[i];
        }
    }
    for (int64_t i = 0; i <= m; i++)
        if (len[i] && to[i] < from[i]) memmove(buf + to[i], buf + from[i], (size_t)len[i]);
    for (int64_t i = m; i >= 0; i--)
        if (len[i] && to[i] > from[i]) memmove(buf + to[i], buf + from[i], (size_t)len[i]);
    for (int64_t i = 0; i < m; i++)
        if (src_len[i] > 0) memcpy(buf + to[i] + len[i], src + src_off[i], (size_t)src_len[i]);
    free(a);
    return 0;
}

/* Number formatting of the rewrite (the twin of textops.format_counts): the fixed-point text of
 * counts[i] * 10**-d, without exponent, with a point always and a '-' only below zero, packed
 * one after the other.  mtc_format_size gives the total size; mtc_format writes the texts into
 * `buf` and their offsets and lengths. */
static inline int format_one(int64_t c, int d, uint8_t *o)
{
    uint8_t tmp[24];
    uint64_t a = c < 0 ? (uint64_t)0 - (uint64_t)c : (uint64_t)c;
    int k = 0, w = 0;
    do { tmp[k++] = (uint8_t)('0' + a % 10); a /= 10; } while (a);
    while (k < d + 1) tmp[k++] = '0';
    if (c < 0) o[w++] = '-';
    for (int j = k - 1; j >= d; j--) o[w++] = tmp[j];
    o[w++] = '.';
    for (int j = d - 1; j >= 0; j--) o[w++] = tmp[j];
    return w;
}

static inline int64_t format_len(int64_t c, int64_t d)
{
    uint64_t a = c < 0 ? (uint64_t)0 - (uint64_t)c : (uint64_t)c;
    int k = 1;
    while (a >= 10) { a /= 10; k++; }
    return (c < 0) + (k > d + 1 ? k : d + 1) + 1;
}

int64_t mtc_format_size(const int64_t *counts, int64_t n, int64_t d)
{
    int64_t total = 0;
    for (int64_t i = 0; i < n; i++) total += format_len(counts[i], d);
    return total;
}

/* The bytes mtc_replace_edits writes for the same rows (-1 for a row out of range). */
int64_t mtc_replace_size(const int64_t *counts, int64_t n_counts, const int64_t *rows, int64_t m,
                         int64_t mult, int64_t d)
{
    int64_t total = 0;
    for (int64_t i = 0; i < m; i++) {
        if (rows[i] < 0 || rows[i] >= n_counts) return -1;
        total += format_len((int64_t)((uint64_t)counts[rows[i]] * (uint64_t)mult), d);
    }
    return total;
}

void mtc_format(const int64_t *counts, int64_t n, int64_t d, uint8_t *buf, int64_t *off, int64_t *len)
{
    int64_t o = 0;
    for (int64_t i = 0; i < n; i++) {
        int w = format_one(counts[i], (int)d, buf + o);
        off[i] = o;
        len[i] = w;
        o += w;
    }
}

/* The replacement edits of one word column of the rewrite (rewrite._column_edits) in one pass,
 * without gathered copies: for each of the m blocks rows[i], the text of counts[rows[i]] * mult
 * at d decimals (as mtc_format of the product) packed into buf, its offset base + (where it
 * starts in buf) in off[i] and its length in len[i], and the span of the block's word of column
 * `col` (cw[rows[i] * stride + col], a word index) in the text: pos[i] = w_num[w], stop[i] =
 * w_end[w].  buf holds n_buf bytes (mtc_replace_size: exactly the texts).  Returns the bytes
 * written to buf, or -1 - i for the first row out of range or without a word (nothing to trust
 * written), or -1 - m if the texts do not fit buf or an offset would not fit 32 bits. */
int64_t mtc_replace_edits(const int64_t *counts, int64_t n_counts, const int64_t *rows, int64_t m,
                          int64_t mult, int64_t d, const int32_t *cw, int64_t stride, int64_t col,
                          const int32_t *w_num, const int32_t *w_end, int64_t n_words,
                          int64_t base, uint8_t *buf, int64_t n_buf, int32_t *pos, int32_t *stop,
                          int32_t *off, int32_t *len)
{
    if (d < 0 || d > 18 || col < 0 || col >= stride || base < 0) return -1 - m;
    if (base + n_buf > 2147483647) return -1 - m;
    int64_t o = 0;
    for (int64_t i = 0; i < m; i++) {
        int64_t r = rows[i];
        if (r < 0 || r >= n_counts) return -1 - i;
        int32_t w = cw[r * stride + col];
        if (w < 0 || w >= n_words) return -1 - i;
        /* (the product wraps as numpy's int64 does) */
        int64_t c = (int64_t)((uint64_t)counts[r] * (uint64_t)mult);
        if (o + format_len(c, d) > n_buf) return -1 - m;
        int k = format_one(c, (int)d, buf + o);
        pos[i] = w_num[w];
        stop[i] = w_end[w];
        off[i] = (int32_t)(base + o);
        len[i] = k;
        o += k;
    }
    return o;
}

/* Replacements by texts of the same length, in place: out[pos[i] : pos[i] + len[i]] =
 * src[src_off[i] : ...] (the ranges do not overlap; the in-place step of textops.splice). */
void mtc_overwrite(uint8_t *out, const uint8_t *src, const int64_t *pos, const int64_t *src_off,
                   const int64_t *len, int64_t m)
{
    for (int64_t i = 0; i < m; i++) memcpy(out + pos[i], src + src_off[i], (size_t)len[i]);
}

/* Byte classes and columns of the read-back (cls: 0 other, 1 a read letter, 2 '(', 3 ';',
 * 4 newline). */
static void read_tables(const int8_t *col, uint8_t *cls, int8_t *colof)
{
    for (int k = 0; k < 256; k++) {
        colof[k] = is_letter((uint8_t)k) ? col[(k | 32) - 97] : -1;
        cls[k] = colof[k] >= 0 ? 1 : k == '(' ? 2 : k == ';' ? 3 : k == '\n' ? 4 : 0;
    }
}

/* The words of the line starting at c[i] into v[column] (v NaN-filled by the caller).
 * Returns the index of the line's end (its newline or n); *bad = 1 if a read letter has no
 * well-formed number or appears twice. */
static int64_t line_words(const uint8_t *c, int64_t n, int64_t i, const uint8_t *cls,
                          const int8_t *colof, double *v, int *bad)
{
    int64_t j = i;
    *bad = 0;
    if (j < n && c[j] == '%') {                 /* a '%' line is a comment */
        const uint8_t *p = memchr(c + j, '\n', (size_t)(n - j));
        return p ? p - c : n;
    }
    while (j < n) {
        uint8_t ch = c[j], k = cls[ch];
        if (k == 0) { j++; continue; }
        if (k == 4) break;
        if (k == 2) {                           /* ( ... ) closed on its line */
            int64_t e = j + 1;
            while (e < n && c[e] != ')' && c[e] != '(' && c[e] != '\n') e++;
            j = (e < n && c[e] == ')') ? e + 1 : j + 1;
            continue;
        }
        if (k == 3) {                           /* ';' to the end of the line */
            const uint8_t *p = memchr(c + j, '\n', (size_t)(n - j));
            return p ? p - c : n;
        }
        int cc = colof[ch];
        j++;
        while (j < n && (c[j] == ' ' || c[j] == '\t' || c[j] == '\r')) j++;
        int64_t s = j, d = -1, nd = 0;
        uint64_t m = 0;
        if (j < n && (c[j] == '-' || c[j] == '+')) j++;
        {
            /* the common number as in mtc_tokenise; the loop below stops at the same byte with
             * the same mantissa, and takes every other number */
            int64_t e, dd;
            int nd8;
            double xv;
            if (j + 17 <= n && common_number8(c, j, &e, &dd, &nd8, &xv)) {
                if (nd8 == 0 || is_num(c[e]) || v[cc] == v[cc]) { *bad = 1; return e; }
                v[cc] = c[s] == '-' ? -xv : xv;
                j = e;
                continue;
            }
        }
        for (; j < n; j++) {
            unsigned dg = (unsigned)c[j] - '0';
            if (dg < 10) { m = m * 10 + dg; nd++; continue; }
            if (c[j] == '.' && d < 0) { d = j; continue; }
            break;
        }
        if (nd == 0 || (j < n && is_num(c[j])) || v[cc] == v[cc]) { *bad = 1; return j; }
        int64_t flen = d >= 0 ? j - d - 1 : 0;
        if (nd <= 15 && nd - flen <= 8 && flen <= 8) {     /* as number(), inline */
            double x = (double)m / POW10[flen];
            v[cc] = c[s] == '-' ? -x : x;
        } else {
            v[cc] = number(c, s, j, d);
        }
    }
    return j;
}

/* To the start of line `want` from position *i on line *line; 0 if the text ends first. */
static int seek_line(const uint8_t *c, int64_t n, int64_t want, int64_t *i, int64_t *line)
{
    while (*line < want) {
        const uint8_t *p = *i < n ? memchr(c + *i, '\n', (size_t)(n - *i)) : NULL;
        if (!p) return 0;
        *i = p - c + 1;
        (*line)++;
    }
    return *line == want && !(*i >= n && want > 0 && (n == 0 || c[n - 1] == '\n'));
}

/* Read-back of the written program for the check of `mtcomp compensate`: for each wanted line
 * (0-based, ascending), the value of its word for every letter with a column in col[26] (-1:
 * not read) into val[i * n_cols + column]; NaN where the line has no such word.  Comments are
 * skipped as mtc_copy_blank_comments finds them, blanks between a letter and its number are read
 * as the parser reads them.  Deliberately independent of the rewrite's bookkeeping (no word
 * positions, no edit list): it finds the words again in the bytes.  Returns -1, or the index
 * (into lines) of the first wanted line where a read letter has no well-formed number or
 * appears twice, or that is beyond the text. */
int64_t mtc_read_words(const uint8_t *c, int64_t n, const int64_t *lines, int64_t n_lines,
                       const int8_t *col, int64_t n_cols, double *val)
{
    const double nan = NAN;     /* positive, as numpy.nan */
    uint8_t cls[256];
    int8_t colof[256];
    read_tables(col, cls, colof);
    int64_t i = 0, line = 0;
    int bad;
    for (int64_t w = 0; w < n_lines * n_cols; w++) val[w] = nan;
    for (int64_t q = 0; q < n_lines; q++) {
        if (!seek_line(c, n, lines[q], &i, &line)) return q;
        int64_t j = line_words(c, n, i, cls, colof, val + q * n_cols, &bad);
        if (bad) return q;
        i = j < n ? j + 1 : n;
        line++;
    }
    return -1;
}

/* Round to the nearest integer, halves to even (numpy.rint; no libm: the library links
 * nothing): adding and taking away 2**52 leaves the rounded value in the default rounding
 * mode; magnitudes from 2**52 are integers already. */
static inline double round_even(double x)
{
    const double two52 = 4503599627370496.0;
    double a = x < 0 ? -x : x;
    if (!(a < two52)) return x;
    a = (a + two52) - two52;
    return x < 0 ? -a : a;
}

/* Where the control stands after each block, in counts (the compiled twin of
 * rewrite._control_counts, same float bits): out[(i + 1) * n + k] for block i and axis k,
 * out[k] the start (start[k], NaN where unknown).  The value of a word: vals[i * n + k] if
 * vals is given (NaN: no word), else wv[cw[i * cw_stride + k]] where that is >= 0.  A word
 * counts rint(value * (inch[i] && lin[k] ? inch_mm : 1) / res[k]) (+ offc[i * n + k] if
 * absolute and offc given); absolute words set the position, G91 (inc[i]) words add to it.
 * Rows where known[i * n + k] is 0 are NaN.  Returns -1, or k * N + i of the first count
 * (axis by axis) above 2**52 in magnitude. */
int64_t mtc_control_counts(int64_t N, int64_t n, const double *vals, const int32_t *cw,
                           int64_t cw_stride, const double *wv, const uint8_t *inc,
                           const uint8_t *inch, const uint8_t *lin, double inch_mm,
                           const double *res, const int64_t *offc, const double *start,
                           const uint8_t *known, double *out)
{
    const double nan = __builtin_nan(""), big = 4503599627370496.0;   /* numpy.nan; 2**52 */
    double p[64];
    int64_t first_bad[64];
    if (n > 64) return -2;                       /* not called so (_ctok.control_counts) */
    for (int64_t k = 0; k < n; k++) {
        p[k] = start[k];
        out[k] = p[k];
        first_bad[k] = -1;
    }
    /* block by block (row-major, cache-friendly), every axis of the block */
    for (int64_t i = 0; i < N; i++) {
        double *o = out + (i + 1) * n;
        for (int64_t k = 0; k < n; k++) {
            double v;
            if (vals) {
                v = vals[i * n + k];
            } else {
                int32_t w = cw[i * cw_stride + k];
                v = w >= 0 ? wv[w] : nan;
            }
            if (v == v) {
                if (inch[i] && lin[k]) v = v * inch_mm;
                double c = round_even(v / res[k]);
                if (c > big || c < -big) {
                    if (first_bad[k] < 0) first_bad[k] = i;
                } else if (inc[i]) {
                    p[k] = p[k] + c;
                } else {
                    p[k] = offc ? c + (double)offc[i * n + k] : c;
                }
            }
            o[k] = known[i * n + k] ? p[k] : nan;
        }
    }
    for (int64_t k = 0; k < n; k++)
        if (first_bad[k] >= 0) return k * N + first_bad[k];
    return -1;
}

/* The rewrite's decisions for one axis column k (the compiled twin of the axis loop of
 * rewrite.rewrite_with_lines): C is the (N + 1) x n matrix of counts (row 0 the start, row i + 1
 * where block i ends).  Per block: the number to write, target[i] (G91: the increment from the
 * previous row; else the count minus the work offset count offc[i * n + k] if given), and
 * whether it is written: in place of the block's word (cw[i * cw_stride + k] >= 0) where that
 * word's own count rint(wv[w] * scale / res) differs, or as a new word where the block has none
 * and the axis moves; only blocks with edit[i], never the Z of no_z[i] blocks (no_z NULL:
 * none).  rep and ins receive the block indices, ascending; their counts are returned in
 * *n_rep, *n_ins. */
void mtc_axis_edits(int64_t N, int64_t n, int64_t k, const int64_t *C, const uint8_t *inc,
                    const int64_t *offc, const int32_t *cw, int64_t cw_stride, const double *wv,
                    double scale, double res, const uint8_t *edit, const uint8_t *no_z,
                    int64_t *target, int64_t *rep, int64_t *ins, int64_t *n_rep, int64_t *n_ins)
{
    int64_t nr = 0, ni = 0;
    for (int64_t i = 0; i < N; i++) {
        int64_t pv = C[i * n + k], v = C[(i + 1) * n + k];
        int64_t t = inc[i] ? v - pv : (offc ? v - offc[i * n + k] : v);
        target[i] = t;
        if (!edit[i]) continue;
        int32_t w = cw[i * cw_stride + k];
        if (w >= 0) {
            int64_t oc = (int64_t)round_even(wv[w] * scale / res);
            if (t != oc) rep[nr++] = i;
        } else if (v != pv && !(no_z && no_z[i])) {
            ins[ni++] = i;
        }
    }
    *n_rep = nr;
    *n_ins = ni;
}

/* The in-place step of textops.splice in one pass over the edits (32-bit arrays as the rewrite
 * makes them): every edit whose text has the length of the range it replaces (and is not
 * empty) is written into out in place; the indices of the other edits that do something (an
 * insertion, a removal, a replacement of another length) go to rest[], their number is
 * returned.  Ranges are checked first: -1 - i for the first edit i outside the buffers
 * (nothing written then). */
int64_t mtc_overwrite_same(uint8_t *out, int64_t n_out, const uint8_t *src, int64_t n_src,
                           const int32_t *pos, const int32_t *stop, const int32_t *src_off,
                           const int32_t *len, int64_t m, int64_t *rest)
{
    for (int64_t i = 0; i < m; i++)
        if (pos[i] < 0 || stop[i] < pos[i] || stop[i] > n_out || src_off[i] < 0 || len[i] < 0
            || (int64_t)src_off[i] + len[i] > n_src)
            return -1 - i;
    int64_t nr = 0;
    for (int64_t i = 0; i < m; i++) {
        int32_t L = len[i];
        if (L > 0 && stop[i] - pos[i] == L) {
            memcpy(out + pos[i], src + src_off[i], (size_t)L);
        } else if (L > 0 || stop[i] > pos[i]) {
            rest[nr++] = i;
        }
    }
    return nr;
}

/* The check of `mtcomp compensate` in one pass, without arrays of the whole program: the
 * words of each block's line (lines[i], as mtc_read_words), through the modal state as
 * mtc_control_counts (same arguments), compared with the counts the rewrite emitted
 * (want[i * n + k]) on the blocks with check[i].  Returns -1 if every checked block reads
 * back as emitted, else the first block that does not, with *kind: 1 a word that cannot be
 * read (or a line past the end), 2 other counts, 3 a count above 2**52. */
int64_t mtc_check_words(const uint8_t *c, int64_t nbytes, const int64_t *lines, int64_t N,
                        int64_t n, const int8_t *col, const uint8_t *inc, const uint8_t *inch,
                        const uint8_t *lin, double inch_mm, const double *res,
                        const int64_t *offc, const double *start, const uint8_t *known,
                        const uint8_t *check, const int64_t *want, int64_t *kind)
{
    const double nan = __builtin_nan(""), big = 4503599627370496.0;
    uint8_t cls[256];
    int8_t colof[256];
    double p[64], v[64];
    if (n > 64) { *kind = 1; return 0; }
    read_tables(col, cls, colof);
    for (int64_t k = 0; k < n; k++) p[k] = start[k];
    int64_t i = 0, line = 0;
    int bad;
    *kind = 0;
    for (int64_t b = 0; b < N; b++) {
        for (int64_t k = 0; k < n; k++) v[k] = nan;
        if (!seek_line(c, nbytes, lines[b], &i, &line)) { *kind = 1; return b; }
        int64_t j = line_words(c, nbytes, i, cls, colof, v, &bad);
        if (bad) { *kind = 1; return b; }
        i = j < nbytes ? j + 1 : nbytes;
        line++;
        int differs = 0;
        for (int64_t k = 0; k < n; k++) {
            double x = v[k];
            if (x == x) {
                if (inch[b] && lin[k]) x = x * inch_mm;
                double cnt = round_even(x / res[k]);
                if (cnt > big || cnt < -big) { *kind = 3; return b; }
                p[k] = inc[b] ? p[k] + cnt : (offc ? cnt + (double)offc[b * n + k] : cnt);
            }
            if (check[b] && !(known[b * n + k] && p[k] == (double)want[b * n + k])) differs = 1;
        }
        if (differs) { *kind = 2; return b; }
    }
    return -1;
}

/* Whether the read-back of the check applies to a program (rewrite._read_back_applies): no
 * G92 word (w_letter 6 with value 92), and on each block's line (block_line[b], 0-based,
 * ascending) exactly as many words with a letter in axis[26] as the block has axis words
 * (cw[b * cw_stride + k] >= 0 for k < n_ax): 1, else 0; -1 if the words are not in text
 * order (w_line ascending). */
int64_t mtc_read_back_applies(const int32_t *w_line, const int8_t *w_letter, const double *w_value,
                              int64_t n_words, const uint8_t *axis, const int64_t *block_line,
                              const int32_t *cw, int64_t cw_stride, int64_t n_ax, int64_t N)
{
    for (int64_t w = 0; w < n_words; w++) {
        if (w > 0 && w_line[w] < w_line[w - 1]) return -1;     /* not in text order */
        if (w_letter[w] == 6 && w_value[w] == 92.0) return 0;
    }
    int64_t w = 0;
    for (int64_t b = 0; b < N; b++) {
        int64_t L = block_line[b], count = 0, have = 0;
        while (w < n_words && w_line[w] < L) w++;
        while (w < n_words && w_line[w] == L) {
            int8_t l = w_letter[w];
            count += l >= 0 && l < 26 && axis[l];
            w++;
        }
        for (int64_t k = 0; k < n_ax; k++) have += cw[b * cw_stride + k] >= 0;
        if (count != have) return 0;
    }
    return 1;
}

/* ---- block building of parse (the twins of numpy passes in parse.py; same values, same bits) */

/* Number of bytes equal to `byte` (vectorised: 32-bit counters in blocks). */
int64_t mtc_count_byte(const uint8_t *b, int64_t n, int64_t byte)
{
    int64_t total = 0;
    for (int64_t i0 = 0; i0 < n; i0 += 1 << 20) {
        int64_t i1 = n - i0 > (1 << 20) ? i0 + (1 << 20) : n;
        uint32_t c = 0;
        for (int64_t i = i0; i < i1; i++) c += b[i] == (uint8_t)byte;
        total += c;
    }
    return total;
}

/* Line starts: 0 and every byte after a line feed (`out` holds count(10) + 1). */
void mtc_line_starts(const uint8_t *b, int64_t n, int64_t *out)
{
    int64_t k = 0;
    out[k++] = 0;
    const uint8_t *p = b, *end = b + n;
    while (p < end) {
        const uint8_t *q = memchr(p, 10, (size_t)(end - p));
        if (!q) break;
        out[k++] = (int64_t)(q - b) + 1;
        p = q + 1;
    }
}

/* Forward fill (parse._ffill): out[i] = values[j] for the last j <= i with isset[j], else
 * `dflt`.  `size`: bytes per value (1, 8); a plain copy, so any 1- or 8-byte type. */
void mtc_ffill(const void *values, const uint8_t *isset, int64_t n, int64_t size,
               const void *dflt, void *out)
{
    if (size == 8) {
        const uint64_t *v = values;
        uint64_t *o = out, cur = *(const uint64_t *)dflt;
        for (int64_t i = 0; i < n; i++) {
            if (isset[i]) cur = v[i];
            o[i] = cur;
        }
    } else {
        const uint8_t *v = values;
        uint8_t *o = out, cur = *(const uint8_t *)dflt;
        for (int64_t i = 0; i < n; i++) {
            if (isset[i]) cur = v[i];
            o[i] = cur;
        }
    }
}

/* Per line: whether it has an axis word (column 0..n_ax-1) and an arc word (column >= n_ax),
 * from each word's column (-1: none) and line.  Returns the number of arc words. */
int64_t mtc_word_lines(const int8_t *wcol, const int32_t *wline, int64_t nw, int64_t n_ax,
                       uint8_t *has_motion, uint8_t *has_arc)
{
    int64_t n_arc = 0;
    for (int64_t i = 0; i < nw; i++) {
        int c = wcol[i];
        if (c < 0) continue;
        if (c < n_ax) has_motion[wline[i]] = 1;
        else { has_arc[wline[i]] = 1; n_arc++; }
    }
    return n_arc;
}

/* The words' scatter into block columns: col_word[b, c] = i and the value[i] for every word
 * i with a column c >= 0 on the line of block b = blk_of_line[wline[i]]: columns below n_ax
 * into vax[b, c] (n_ax per row), the others into varc[b, c - n_ax]; -1 and NaN elsewhere
 * (written here).  Returns -1, or the first word whose line is no block (the caller then
 * takes the numpy path, which decides what that means). */
int64_t mtc_scatter(const int8_t *wcol, const int32_t *wline, const double *value, int64_t nw,
                    const int64_t *blk_of_line, int64_t nblk, int64_t ncol, int64_t n_ax,
                    int32_t *col_word, double *vax, double *varc)
{
    const double nan = NAN;
    int64_t na = ncol - n_ax;
    for (int64_t j = 0; j < nblk * ncol; j++) col_word[j] = -1;
    for (int64_t j = 0; j < nblk * n_ax; j++) vax[j] = nan;
    for (int64_t j = 0; j < nblk * na; j++) varc[j] = nan;
    for (int64_t i = 0; i < nw; i++) {
        int c = wcol[i];
        if (c < 0) continue;
        int64_t b = blk_of_line[wline[i]];
        if (b < 0) return i;
        col_word[b * ncol + c] = (int32_t)i;
        if (c < n_ax) vax[b * n_ax + c] = value[i];
        else varc[b * na + c - n_ax] = value[i];
    }
    return -1;
}

/* Absolute positions (parse._absolute), per axis in the order of numpy's operations:
 * cum = cumsum(where(present & incremental, v, 0)), then at a row after the last absolute
 * word j: (v[j] - cum[j] (+ offset[j])) + cum, before any: start + cum.  Strides in elements
 * (the value and presence arrays are column slices of wider arrays).  One pass over the rows
 * with every axis' running state (a pass per axis read each row's cache lines once per
 * axis); each axis' arithmetic is the same sequence as its own pass. */
void mtc_absolute(int64_t n, int64_t n_ax, const double *vals, int64_t vs, const uint8_t *present,
                  int64_t ps, const uint8_t *incremental, const double *offset, int64_t use_off,
                  const double *start, double *position)
{
    enum { MAXAX = 32 };
    double cum[MAXAX], base[MAXAX];
    int have[MAXAX];
    for (int64_t k0 = 0; k0 < n_ax; k0 += MAXAX) {       /* (more axes than that: in groups) */
        int64_t k1 = n_ax - k0 < MAXAX ? n_ax : k0 + MAXAX;
        for (int64_t k = k0; k < k1; k++) { cum[k - k0] = 0.0; base[k - k0] = 0.0; have[k - k0] = 0; }
        for (int64_t i = 0; i < n; i++) {
            int incr = incremental[i] != 0;
            const double *v = vals + i * vs;
            const uint8_t *pr = present + i * ps;
            double *out = position + i * n_ax;
            for (int64_t k = k0; k < k1; k++) {
                int64_t q = k - k0;
                int pres = pr[k] != 0;
                double inc = pres && incr ? v[k] : 0.0;
                cum[q] = i ? cum[q] + inc : inc;
                if (pres && !incr) {
                    base[q] = v[k] - cum[q];
                    if (use_off) base[q] += offset[i * n_ax + k];
                    have[q] = 1;
                }
                out[k] = (have[q] ? base[q] : start[k]) + cum[q];
            }
        }
    }
}

/* Per column k of the (n, n_col) rows of P (row stride `stride` elements): whether every value
 * lies in [lo[k], hi[k]] (no NaN), into ok[k] (the travel checks' `P[:, k].min() >= lo and
 * P[:, k].max() <= hi`, numpy's min and max propagating NaN), in one pass over the rows
 * instead of two strided passes per column. */
void mtc_columns_within(const double *P, int64_t n, int64_t n_col, int64_t stride,
                        const double *lo, const double *hi, uint8_t *ok)
{
    enum { MAXC = 64 };
    uint8_t good[MAXC];
    for (int64_t k0 = 0; k0 < n_col; k0 += MAXC) {
        int64_t k1 = n_col - k0 < MAXC ? n_col : k0 + MAXC;
        for (int64_t k = k0; k < k1; k++) good[k - k0] = 1;
        for (int64_t i = 0; i < n; i++) {
            const double *row = P + i * stride;
            for (int64_t k = k0; k < k1; k++) {
                double x = row[k];
                good[k - k0] &= (uint8_t)((x >= lo[k]) & (x <= hi[k]));   /* NaN: both false */
            }
        }
        for (int64_t k = k0; k < k1; k++) ok[k] = good[k - k0];
    }
}

/* textops.decimal_values over (n, n_col) rows, C order: out = counts as float64 (src int64 if
 * is_int, else float64), then per column k: where max |value| (NaN skipped, 0 if none) times
 * mult[k] reaches 2**53, value * res[k]; else (value * mult[k] where mult[k] != 1) / p10[k] --
 * numpy's operations in its order, each rounded as numpy rounds it.  out may be src itself
 * (each element read before it is written; through memcpy: no aliasing assumption). */
void mtc_decimal_values(const void *src, int64_t is_int, int64_t n, int64_t n_col,
                        const double *mult, const double *p10, const double *res, double *out)
{
    enum { MAXC = 64 };
    double mx[MAXC];
    int big[MAXC];
    const unsigned char *s = (const unsigned char *)src;
    if (n_col > MAXC) return;
    for (int64_t k = 0; k < n_col; k++) mx[k] = 0.0;
    for (int64_t i = 0; i < n * n_col; i += n_col) {
        for (int64_t k = 0; k < n_col; k++) {
            double x;
            if (is_int) { int64_t c; memcpy(&c, s + 8 * (i + k), 8); x = (double)c; }
            else memcpy(&x, s + 8 * (i + k), 8);
            double a = fabs(x);
            if (a > mx[k]) mx[k] = a;                      /* NaN: never greater */
        }
    }
    for (int64_t k = 0; k < n_col; k++) big[k] = mx[k] * mult[k] >= 9007199254740992.0;
    for (int64_t i = 0; i < n * n_col; i += n_col) {
        for (int64_t k = 0; k < n_col; k++) {
            double x;
            if (is_int) { int64_t c; memcpy(&c, s + 8 * (i + k), 8); x = (double)c; }
            else memcpy(&x, s + 8 * (i + k), 8);
            if (big[k]) x = x * res[k];
            else {
                if (mult[k] != 1.0) x = x * mult[k];
                x = x / p10[k];
            }
            memcpy((unsigned char *)out + 8 * (i + k), &x, 8);
        }
    }
}
