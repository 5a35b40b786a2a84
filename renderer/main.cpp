#include "renderer/cli.h"

int main(int argc, char** argv) { return iso::runCommandLine(argc, argv); }
