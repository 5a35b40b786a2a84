#pragma once
// The isotrace command line (DESIGN.md, "Command line"). Exit status: 0 success, 2 bad
// input (one line on stderr naming the file and the place), 1 internal error.
namespace iso {
int runCommandLine(int argc, char** argv);
}
