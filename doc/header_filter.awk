# Doxygen input filter (doc/Doxyfile): the public headers' comments are plain `//` prose; this turns them
# into Doxygen comments on the fly, so the headers carry no Doxygen markup.
#  - the comment block at the top of a header documents the file (`/// \file` is put before it);
#  - a comment on a line of its own documents what follows it;
#  - a comment after `;` or `,` on a declaration's line documents that declaration (`///<`);
#  - `<` and `>` in comments are escaped: they are prose (`truth/lines/<stem>.csv`, `a -> b`), not HTML.
# Line numbers of warnings are one too high after a file comment (the inserted `\file` line).
function escape(text) {
  gsub(/</, "\\<", text)
  gsub(/>/, "\\>", text)
  return text
}
BEGIN { at_top = 1 }
{
  line = $0
  if (at_top) {
    if (line ~ /^\/\//) {
      if (!file_started) {
        print "/// \\file"
        file_started = 1
      }
      sub(/^\/\//, "///", line)
      print escape(line)
      next
    }
    at_top = 0
  }
  if (line ~ /^[ \t]*\/\/([^\/]|$)/) {
    sub(/\/\//, "///", line)
    print escape(line)
    next
  }
  if (match(line, /[;,][ \t]+\/\/ /)) {
    head = substr(line, 1, RSTART + RLENGTH - 4)
    rest = substr(line, RSTART + RLENGTH - 3)
    sub(/^\/\/ /, "", rest)
    line = head "///< " escape(rest)
  }
  print line
}
