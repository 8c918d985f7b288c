/* Preloaded (LD_PRELOAD) into a coverage build of ArduPilot SITL, whose own exit on SIGTERM waits
 * for its simulated clock, which nothing advances once its flight is over: SIGUSR1 ends it through
 * exit(), whose handlers write gcov's counters. Built beside the variant (harness/firmware/builds.py). */
#include <signal.h>
#include <stdlib.h>

static void exit_in_order(int signum)
{
	(void)signum;
	exit(0);
}

__attribute__((constructor)) static void install(void)
{
	signal(SIGUSR1, exit_in_order);
}
