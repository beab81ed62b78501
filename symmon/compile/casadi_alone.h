/* symmon: what CasADi's generated C defines before the symmon C that follows it in a
   kernel's source (CasADi's defaults).  Only the block of a file checked alone includes
   this header (symmon.compile.csource); a kernel's source never does. */
#ifndef SYMMON_CASADI_ALONE_H
#define SYMMON_CASADI_ALONE_H
#define casadi_real double
#define casadi_int long long int
#define CASADI_SYMBOL_EXPORT
#endif
