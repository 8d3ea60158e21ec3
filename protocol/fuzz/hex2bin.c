/* Turns a golden-frame .hex file (protocol/vectors/README.md) into the raw bytes, for the fuzzer's seed
 * corpus:  hex2bin in.hex out.bin */
#include <stdio.h>

int main(int argc, char** argv) {
  if (argc != 3) return 2;
  FILE* in = fopen(argv[1], "r");
  FILE* out = fopen(argv[2], "wb");
  if (in == NULL || out == NULL) return 1;
  int c;
  int digits = 0;
  unsigned value = 0;
  while ((c = fgetc(in)) != EOF) {
    if (c == '#') {
      while (c != EOF && c != '\n') c = fgetc(in);
      continue;
    }
    int v = -1;
    if (c >= '0' && c <= '9') v = c - '0';
    if (c >= 'a' && c <= 'f') v = c - 'a' + 10;
    if (c >= 'A' && c <= 'F') v = c - 'A' + 10;
    if (v < 0) continue;
    value = value * 16u + (unsigned)v;
    if (++digits == 2) {
      fputc((int)value, out);
      digits = 0;
      value = 0;
    }
  }
  fclose(in);
  return fclose(out) == 0 ? 0 : 1;
}
